"""The navigation solution of a batch of runs, and the error state as a layout of named blocks.

* :class:`NavState` — what a filter carries and corrects: position, velocity, attitude and the
  bias compensation subtracted from the IMU, batched over runs (and points).
* :class:`StateLayout` — which error-state blocks an experiment estimates, in which order
  (``--state``): ``pos`` (position, NED metres), ``vel`` (velocity, NED m/s), ``att``
  (attitude, nav-frame rad), ``ba`` / ``bg`` (residual accelerometer / gyro biases, body frame).
  The papers' 12-state error ``[δv, δψ, b_a, b_g]`` is the layout ``12``; ``15`` puts position
  first, ``[δp, δv, δψ, b_a, b_g]``. Blocks always come in the order of :data:`BLOCK_ORDER`.

Every block is a correction: ``nav ⊕ x = truth`` (:func:`plus`); :func:`error` is its inverse
``truth ⊖ nav`` per block. Conventions: docs/conventions.md.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from nespm_cli.errors import NespmError
from nespm_cli.nav.earth import ned_offset, radii
from nespm_cli.nav.rotations import attitude_minus, attitude_plus
from nespm_cli.nav.trig import sin_cos

#: block -> (size, unit, component labels); the order in which blocks sit in the state vector
BLOCKS = {
    "pos": (3, "m", ("dpN", "dpE", "dpD")),
    "vel": (3, "m/s", ("dvN", "dvE", "dvD")),
    "att": (3, "rad", ("dpsiN", "dpsiE", "dpsiD")),
    "ba": (3, "m/s^2", ("baX", "baY", "baZ")),
    "bg": (3, "rad/s", ("bgX", "bgY", "bgZ")),
}
BLOCK_ORDER = tuple(BLOCKS)
REQUIRED = ("vel", "att")  # every filter of this bench estimates these
#: named layouts; any comma list of blocks (with vel and att) is a layout too
LAYOUTS = {"12": ("vel", "att", "ba", "bg"), "15": ("pos", "vel", "att", "ba", "bg")}


@dataclass
class NavState:
    """Navigation solution of R runs (leading shape ``B``, usually (R,)).

    ``pos`` (B, 3) ``[lat rad, lon rad, h m]``, ``v_n`` (B, 3) NED [m/s], ``C_bn`` (B, 3, 3) and the
    accumulated bias compensation ``b_a`` (B, 3) [m/s²], ``b_g`` (B, 3) [rad/s] subtracted from the IMU.
    """

    pos: np.ndarray
    v_n: np.ndarray
    C_bn: np.ndarray
    b_a: np.ndarray
    b_g: np.ndarray = field(default=None)

    def copy(self) -> "NavState":
        return NavState(self.pos.copy(), self.v_n.copy(), self.C_bn.copy(), self.b_a.copy(), self.b_g.copy())


@dataclass(frozen=True)
class StateLayout:
    """The blocks of an error state, in :data:`BLOCK_ORDER` (``blocks``); ``n`` states in all."""

    blocks: tuple = LAYOUTS["12"]

    def __post_init__(self) -> None:
        unknown = [b for b in self.blocks if b not in BLOCKS]
        if unknown:
            raise NespmError(f"--state: unknown block {unknown[0]!r}; blocks are {', '.join(BLOCK_ORDER)} "
                             f"(or a layout: {', '.join(LAYOUTS)})")
        if len(set(self.blocks)) != len(self.blocks):
            raise NespmError(f"--state: a block is given twice in {','.join(self.blocks)}")
        missing = [b for b in REQUIRED if b not in self.blocks]
        if missing:
            raise NespmError(f"--state: every layout holds {' and '.join(REQUIRED)}; {','.join(self.blocks)} lacks "
                             f"{missing[0]}")
        object.__setattr__(self, "blocks", tuple(b for b in BLOCK_ORDER if b in self.blocks))

    @property
    def n(self) -> int:
        """Number of error states."""
        return _index(self.blocks)[1]

    @property
    def name(self) -> str:
        """``12``, ``15`` or the comma list of blocks."""
        for k, v in LAYOUTS.items():
            if v == self.blocks:
                return k
        return ",".join(self.blocks)

    def has(self, block: str) -> bool:
        return block in self.blocks

    def slice(self, block: str) -> slice:
        """The index range of ``block`` (a NespmError if the layout lacks it)."""
        s = _index(self.blocks)[0].get(block)
        if s is None:
            raise NespmError(f"the state layout {self.name} has no {block} block")
        return s

    def offset(self, block: str) -> int:
        """First index of ``block``, or -1 without it (what the compiled loops take)."""
        return self.slice(block).start if self.has(block) else -1

    def offsets(self) -> np.ndarray:
        """``[pos, vel, att, ba, bg]`` first indices (int64, -1 for an absent block; a new array)."""
        return _index(self.blocks)[2].copy()

    @property
    def labels(self) -> tuple[str, ...]:
        """One label per state (``dpN``, ..., ``bgZ``)."""
        return tuple(lab for b in self.blocks for lab in BLOCKS[b][2])


@lru_cache(maxsize=None)
def _index(blocks: tuple) -> tuple[dict, int, np.ndarray]:
    """``({block: slice}, n, offsets)`` of the blocks ``blocks`` (in :data:`BLOCK_ORDER`), computed once per
    layout: the filters ask for them at every epoch (callers copy ``offsets``, never write it)."""
    slices, i = {}, 0
    for b in blocks:
        slices[b] = slice(i, i + BLOCKS[b][0])
        i += BLOCKS[b][0]
    return slices, i, np.array([slices[b].start if b in slices else -1 for b in BLOCK_ORDER], dtype=np.int64)


LAYOUT_12 = StateLayout(LAYOUTS["12"])  # the papers' [dv, dpsi, b_a, b_g]
LAYOUT_15 = StateLayout(LAYOUTS["15"])  # [dp, dv, dpsi, b_a, b_g]


def parse_layout(text: str | StateLayout) -> StateLayout:
    """``"12"``, ``"15"`` or a comma list of blocks (``"pos,vel,att,ba,bg"``) -> StateLayout."""
    return text if isinstance(text, StateLayout) else _parsed(str(text))


@lru_cache(maxsize=None)  # a StateLayout is immutable, and FilterConfig.layout asks at every epoch
def _parsed(text: str) -> StateLayout:
    t = text.strip().lower()
    blocks = LAYOUTS.get(t) or tuple(b.strip() for b in t.split(",") if b.strip())
    return StateLayout(tuple(blocks))


def position_plus(pos: np.ndarray, dp: np.ndarray) -> np.ndarray:
    """``pos ⊕ δp``: ``[lat, lon, h]`` (..., 3) moved by the NED offset ``δp`` (..., 3) [m]
    (the inverse of :func:`nespm_cli.nav.earth.ned_offset` about ``pos``)."""
    R_N, R_E = radii(pos[..., 0])
    lat = pos[..., 0] + dp[..., 0] / (R_N + pos[..., 2])
    lon = pos[..., 1] + dp[..., 1] / ((R_E + pos[..., 2]) * sin_cos(pos[..., 0])[1])
    return np.stack([lat, lon, pos[..., 2] - dp[..., 2]], axis=-1)


def plus(nav: NavState, x: np.ndarray, layout: StateLayout) -> None:
    """Close the loop in place: ``nav ⊕ x`` for every block of ``layout`` (biases into the
    compensation). ``x`` (B, n); afterwards the filter's estimate is zero."""
    if layout.has("pos"):
        nav.pos = position_plus(nav.pos, x[..., layout.slice("pos")])
    nav.v_n = nav.v_n + x[..., layout.slice("vel")]
    nav.C_bn = attitude_plus(nav.C_bn, x[..., layout.slice("att")])
    if layout.has("ba"):
        nav.b_a = nav.b_a + x[..., layout.slice("ba")]
    if layout.has("bg"):
        nav.b_g = nav.b_g + x[..., layout.slice("bg")]


def error(layout: StateLayout, pos_true, v_true, C_true, b_a_true, b_g_true, nav: NavState) -> np.ndarray:
    """``truth ⊖ nav`` (..., n) per block: NED position offset [m], velocity difference, attitude
    ``C_true ⊖ C_nav`` [rad], and the residual biases ``b_true − b̂`` (what the state estimates)."""
    parts = {
        "pos": lambda: ned_offset(pos_true, nav.pos),
        "vel": lambda: v_true - nav.v_n,
        "att": lambda: attitude_minus(C_true, nav.C_bn),
        "ba": lambda: b_a_true - nav.b_a,
        "bg": lambda: b_g_true - nav.b_g,
    }
    return np.concatenate([np.broadcast_to(parts[b](), np.shape(nav.v_n)) for b in layout.blocks], axis=-1)


__all__ = ["BLOCKS", "BLOCK_ORDER", "LAYOUTS", "LAYOUT_12", "LAYOUT_15", "NavState", "StateLayout", "error", "parse_layout", "plus",
           "position_plus"]
