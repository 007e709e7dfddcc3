"""How far off the simulated phones' own fixes are, per regime: today's physics and streets as
harsh as real ones (``scenes.HARSH``, issue 48).

Per regime (the street regimes of ``scenes.REGIMES`` and the walked district), over scenes:
the fixes' error (RMS, m per axis, every epoch of every receiver once), how many times larger
it is than the phones claim (RMS error over RMS claimed ``position_sd``), how far the fixes
lean across the street away from its taller side (the mean error across it; streets only: the
district's walks run both ways), and how long an error lasts (the lag, s, at which its
autocorrelation falls below 1/e; the median over receivers). Cells: the median over the
scenes, and their range.

    python fixes.py [--scenes 10]
"""

from __future__ import annotations

import argparse

import numpy as np
import pandas as pd
from scenes import REGIMES, harsh, random_physics, regime_scene

from gnss_citygml.simulate import simulate

#: The regimes measured: the streets' and the walked district.
MEASURED = (*REGIMES, "district")


def fix_figures(sim) -> dict[str, float]:
    """One simulated scene's fixes: RMS error per axis, its ratio to the claimed error, the
    mean error across the street away from its taller side, and the error's duration."""
    fixes = sim.observations.drop_duplicates(["receiver", "time_utc"])
    de = (fixes["e"] - fixes["e_true"]).to_numpy()
    dn = (fixes["n"] - fixes["n_true"]).to_numpy()
    rms = float(np.sqrt(np.mean((de**2 + dn**2) / 2.0)))
    claimed = float(np.sqrt(np.mean(fixes["position_sd"].to_numpy() ** 2)))
    return {
        "rms": rms,
        "ratio": rms / claimed,
        "away": float(np.mean(dn)) * _taller_south(sim),
        "seconds": _duration(fixes, de),
    }


def _taller_south(sim) -> float:
    """+1 where a street's south row is the taller on average (the receivers between the rows,
    north of the south row: an error away from it is northward), -1 where the north row is."""
    truth = sim.truth.assign(side=sim.truth["id"].str.extract(r"street_([sn])", expand=False))
    rows = (truth["height"] - truth["ground"]).groupby(truth["side"]).mean()
    return 1.0 if rows.get("s", 0.0) >= rows.get("n", 0.0) else -1.0


def _duration(fixes: pd.DataFrame, error: np.ndarray) -> float:
    """The median over receivers of the lag (s) at which the east error's autocorrelation
    first falls below 1/e."""
    lags = []
    for _, rows in fixes.groupby("receiver").indices.items():
        x = error[rows] - error[rows].mean()
        if x.size < 10 or not np.any(x):
            continue
        acf = np.correlate(x, x, "full")[x.size - 1 :] / np.dot(x, x)
        below = np.flatnonzero(acf < np.exp(-1.0))
        step = (fixes["time_utc"].iloc[rows[1]] - fixes["time_utc"].iloc[rows[0]]).total_seconds()
        lags.append((below[0] if below.size else x.size) * step)
    return float(np.median(lags)) if lags else float("nan")


def _cell(values: list[float], digits: int = 1) -> str:
    v = np.asarray(values)
    return f"{np.median(v):.{digits}f} ({v.min():.{digits}f}-{v.max():.{digits}f})"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=10)
    args = parser.parse_args()
    print(
        "| regime | physics | error, m per axis (RMS) | error / claimed | away from the taller "
        "side, m | lasts, s |"
    )
    print("|---|---|---|---|---|---|")
    for regime in MEASURED:
        for name in ("today", "harsh"):
            figures = []
            for k in range(args.scenes):
                scene, start, _ = regime_scene(k, regime)
                physics = random_physics(k)
                physics = harsh(k, physics) if name == "harsh" else physics
                sim = simulate(scene, locations="gnss", seed=k, start=start, physics=physics)
                figures.append(fix_figures(sim))
            table = pd.DataFrame(figures)
            away = "-" if regime == "district" else _cell(table["away"])
            print(
                f"| {regime} | {name} | {_cell(table['rms'])} | {_cell(table['ratio'], 2)} | "
                f"{away} | {_cell(table['seconds'], 0)} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
