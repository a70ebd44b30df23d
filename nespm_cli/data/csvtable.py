"""Reading and writing the CSV tables of a track folder (GT, DVL, IMU and the optional sensor files).

Every failure raises :class:`~nespm_cli.errors.NespmError` with a one-line message
``"<file>: data row R, column 'C': ..."``; *data rows* are numbered from 1 after the header line.
Header names are compared with surrounding whitespace removed. Used by
:mod:`nespm_cli.data.tracks` and :mod:`nespm_cli.data.sensor_files`.
"""
from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from nespm_cli.data.atomic import write_atomic
from nespm_cli.data.plausibility import printable
from nespm_cli.errors import NespmError

QUOTE_LIMIT = 40  # characters of file content quoted in a message (printable only)


def link_problem(path: Path) -> str | None:
    """Why ``path``, a symbolic link, cannot be followed (``"a symbolic link loop"``, ``"a broken symbolic link to
    X"``), or None when it is no link or can be followed."""
    if not path.is_symlink():
        return None
    try:
        path.resolve(strict=True)
    except RuntimeError:
        return "a symbolic link loop (it never reaches a file)"
    except OSError as exc:
        import errno

        if exc.errno == errno.ELOOP:
            return "a symbolic link loop (it never reaches a file)"
        return f"a broken symbolic link (to {printable(str(path.readlink()), QUOTE_LIMIT)}, which does not exist)"
    return None


def read_frame(path: Path) -> pd.DataFrame:
    """The CSV ``path`` as a DataFrame (every cell as parsed, header names stripped); refuses a missing,
    unreadable, binary, empty (no header line) or unparsable file. A header-only file gives 0 rows."""
    import pandas as pd  # here, not at the top: `nespm --help` and the embedded tracks need no pandas

    if not path.is_file():
        raise NespmError(f"{path}: {link_problem(path) or 'file not found'}")
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise NespmError(f"{path}: cannot read the file ({printable(exc.strerror or exc, QUOTE_LIMIT)})") from None
    nul = raw.count(b"\x00")
    if nul:
        first = raw.index(b"\x00")
        raise NespmError(
            f"{path}: not a readable CSV file (binary content: {nul} NUL byte{'s' if nul != 1 else ''}, "
            f"first at byte {first})"
        )
    try:
        df = pd.read_csv(io.BytesIO(raw), encoding="utf-8-sig")
    except pd.errors.EmptyDataError:
        raise NespmError(f"{path}: empty file") from None
    except (pd.errors.ParserError, UnicodeDecodeError, ValueError) as exc:
        raise NespmError(f"{path}: not a readable CSV file ({printable(exc, 100)})") from None
    except Exception as exc:  # noqa: BLE001 - any other parser failure is a bad file, not a crash
        raise NespmError(f"{path}: not a readable CSV file ({type(exc).__name__}: {printable(exc, 100)})") from None
    df.columns = [str(c).strip() for c in df.columns]
    return df


def header_text(df: pd.DataFrame) -> str:
    """The file's header names, printable, for a message."""
    return printable(", ".join(printable(c, QUOTE_LIMIT) for c in df.columns), 120)


def require_columns(path: Path, df: pd.DataFrame, columns: tuple[str, ...]) -> None:
    """Refuse a header without one of ``columns`` or with one of them twice."""
    for col in columns:
        if col not in df.columns:
            raise NespmError(f"{path}: missing column '{col}' (header has: {header_text(df)})")
        if list(df.columns).count(col) > 1:
            raise NespmError(f"{path}: column '{col}' appears more than once in the header")


def to_array(path: Path, df: pd.DataFrame, columns: tuple[str, ...], nan_ok: tuple[str, ...] = ()) -> np.ndarray:
    """``columns`` of ``df`` as a float array (rows, len(columns)): refuses non-numeric text and any
    non-finite value, except NaN (an empty cell or ``nan``) in the columns ``nan_ok``."""
    import pandas as pd

    out = np.empty((len(df), len(columns)))
    for j, col in enumerate(columns):
        s = df[col]
        if not pd.api.types.is_numeric_dtype(s.dtype):
            num = pd.to_numeric(s, errors="coerce")
            bad = np.flatnonzero((num.isna() & s.notna()).to_numpy())
            if bad.size:
                r = int(bad[0])
                text = printable(s.iloc[r], QUOTE_LIMIT)
                raise NespmError(f"{path}: data row {r + 1}, column '{col}': not a number ('{text}')")
            s = num
        out[:, j] = s.to_numpy(dtype=float)
    allowed = np.array([c in nan_ok for c in columns], dtype=bool)
    bad_cells = ~np.isfinite(out) & ~(np.isnan(out) & allowed)
    bad_rows = np.flatnonzero(bad_cells.any(axis=1))
    if bad_rows.size:
        r = int(bad_rows[0])
        j = int(np.flatnonzero(bad_cells[r])[0])
        what = "infinite value (only NaN, no measurement, is allowed)" if allowed[j] else "missing or non-finite value"
        raise NespmError(f"{path}: data row {r + 1}, column '{columns[j]}': {what} ({float(out[r, j])})")
    return out


def read_table(path: Path, columns: tuple[str, ...], nan_ok: tuple[str, ...] = ()) -> np.ndarray:
    """Read ``columns`` of the CSV ``path`` (at least 2 data rows; extra columns ignored) as a float
    array (rows, len(columns)), finite except NaN in the columns ``nan_ok``."""
    df = read_frame(path)
    require_columns(path, df, columns)
    if len(df) == 0:
        raise NespmError(f"{path}: no data rows after the header")
    if len(df) < 2:
        raise NespmError(f"{path}: needs at least 2 data rows, has {len(df)}")
    return to_array(path, df, columns, nan_ok)


def check_nan_rows(path: Path, values: np.ndarray, columns: tuple[str, ...], what: str) -> None:
    """Refuse a row of ``values`` (rows, len(columns)) with some but not all entries NaN; a row of
    NaN is ``what`` (e.g. "a missing epoch")."""
    nan = np.isnan(values)
    bad = np.flatnonzero(nan.any(axis=1) & ~nan.all(axis=1))
    if bad.size:
        r = int(bad[0])
        cols = ", ".join(f"'{c}'" for c in columns)
        missing = ", ".join(f"'{columns[j]}'" for j in np.flatnonzero(nan[r]))
        raise NespmError(f"{path}: data row {r + 1}, columns {cols}: NaN in {missing} only; NaN must be in all "
                         f"of them ({what}) or in none")


def write_table(path: Path, data: np.ndarray, columns: tuple[str, ...]) -> None:
    """Write ``data`` under the header ``columns`` at full precision (``%.17g``, NaN as ``nan``),
    atomically (:func:`nespm_cli.data.atomic.write_atomic`)."""
    import pandas as pd

    frame = pd.DataFrame(np.asarray(data, dtype=float).reshape(-1, len(columns)), columns=list(columns))
    write_atomic(path, lambda tmp: frame.to_csv(tmp, index=False, float_format="%.17g", na_rep="nan"))
