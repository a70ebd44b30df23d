"""The filters' numba kernels: the loops over one time-update span that run at the IMU rate, for every run
(and sigma point) of a batch. Called through :mod:`nespm_cli.filters.kernels` (the switch between them and
the NumPy reference), never directly by a filter.

* :mod:`.spans` — the generic loops: Φ = Π (I + F dt) of any layout, the 15 states with F's zeros skipped,
  the iekf's invariant Φ, and the sigma/cubature points one at a time;
* :mod:`.entries` — F's entries on the velocity and attitude rows, shared by the unrolled Φ kernels;
* :mod:`.unrolled_12` — the papers' 12-state Φ written out, run by run;
* :mod:`.lanes_12` — the same with the runs in SIMD lanes (from ``kernels.LANES_MIN`` runs);
* :mod:`.lanes_15` — the 15 states' Φ with the runs in SIMD lanes (from ``kernels.LANES_MIN_15`` runs);
* :mod:`.cycle_lanes` — the navigation cycle of a table of states in SIMD lanes;
* :mod:`.points` — a run's sigma/cubature points through the cycle in SIMD lanes.

Each gives the bits of the generic loop and of the NumPy reference (tests/test_compile_kernels.py,
tests/test_points_kernel.py, tests/test_kernels.py).
"""
