"""``nespm warm-up``: compile the filters' numba kernels into the per-user cache, once (CI images, a
new machine), so that later commands load them instead of compiling (docs/architecture.md)."""
from __future__ import annotations

from typing import Optional

import typer

from nespm_cli.errors import NespmError


def warm_up_cmd(
    filters_: Optional[str] = typer.Option(None, "--filters", help="Comma list of filters whose kernels to compile (default: every kernel)."),
    state: str = typer.Option("12", "--state", help="Error-state layout of --filters: 12 or 15."),
) -> None:
    """Compile the filters' kernels into the per-user cache ($NESPM_CACHE_DIR, else ~/.cache/nespm);
    later commands on this machine, from any install or clone of the same version, load them."""
    from nespm_cli.experiments.progress import kernels_for
    from nespm_cli.filters.kernels import KERNELS, compiled_enabled, kernels_cached, warm_up
    from nespm_cli.nav.state import parse_layout

    if not compiled_enabled():
        typer.echo("warm-up: nothing to compile: the compiled kernels are not in use (--kernels numpy, "
                   "$NESPM_KERNELS=numpy, or numba is not installed)")
        return
    names = KERNELS
    if filters_ is not None:
        from nespm_cli.filters.registry import filter_names

        chosen = [f.strip() for f in filters_.split(",") if f.strip()]
        unknown = [f for f in chosen if f not in filter_names()]
        if unknown or not chosen:
            raise NespmError(f"--filters: unknown filter {', '.join(unknown) or repr(filters_)}; choose from "
                             f"{', '.join(filter_names())}")
        names = kernels_for(chosen, parse_layout(state), runs=None)
    from nespm_cli.nav.kernel_cache import cache_folder

    where = cache_folder()
    cached = kernels_cached(names)
    if cached:
        typer.echo(f"warm-up: {len(names)} kernel(s) already compiled in {where}")
        return
    seconds = warm_up(names)
    place = (f"into {where}" if cached is False else
             "(the per-user cache folder is not writable: set NESPM_CACHE_DIR; numba's own cache place, if any, keeps them)")
    typer.echo(f"warm-up: compiled {', '.join(names)} in {seconds:.1f} s {place}")
