"""Published values of the papers' tables (anukf.md Tables I-II, ukf-nespm.md Table I)."""
from __future__ import annotations

from typing import Any, Sequence


#: Published track-averaged results (real Snapir tracks 5 and 6, authors' recorded IMU).
#: ``values`` maps our filter name to ``{"vrmse": m/s, "mrmse": rad}`` (table order);
#: ``reference`` is the table's proposed method, whose 'Imprv.' over each row is shown.
PUBLISHED: dict[str, dict[str, Any]] = {
    "anukf-table1": {
        "source": "anukf.md Table I",
        "scenario": "nominal",
        "reference": "anukf",
        "values": {
            "ukf": {"vrmse": 0.1172, "mrmse": 0.0112},
            "anekf": {"vrmse": 0.1004, "mrmse": 0.0156},
            "anukf": {"vrmse": 0.0922, "mrmse": 0.0106},
        },
    },
    "anukf-table2": {
        "source": "anukf.md Table II (20 s DVL outage from t = 180 s)",
        "scenario": "outage",
        "reference": "anukf",
        "values": {
            "anekf": {"vrmse": 0.222, "mrmse": 0.0156},
            "anukf": {"vrmse": 0.1183, "mrmse": 0.0106},
        },
    },
    "ukf-nespm-table1": {
        "source": "ukf-nespm.md Table I",
        "scenario": "nominal",
        "reference": "anukf-nespm",
        "values": {
            "anukf-nespm": {"vrmse": 0.073, "mrmse": 0.0065},
            "anukf": {"vrmse": 0.08, "mrmse": 0.0079},
        },
    },
}


def published_tables(filters: Sequence[str], scenario: str | None, min_filters: int = 1) -> list[dict[str, Any]]:
    """The entries of :data:`PUBLISHED` for ``scenario`` that have rows for at least
    ``min_filters`` of ``filters`` (the report shows those with at least two)."""
    return [
        entry
        for entry in PUBLISHED.values()
        if entry["scenario"] == scenario and len(set(entry["values"]) & set(filters)) >= min_filters
    ]
