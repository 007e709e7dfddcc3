"""How much of the phones' fix errors can shadow matching take back? (issue 28, a floor)

For each window of a recording, one horizontal shift of its fixes, by the package's shadow
matching (:mod:`gnss_citygml.calibrate.shadows`: the posterior mean over a grid of candidates,
a Gaussian prior of the window's reported error) against footprints with known ``heights``.

What a signal says: with ``labels="los"`` the simulator's line of sight (a perfect classifier:
the floor of shadow matching itself), with ``"cn0"`` whether it arrives strong (C/N0 at or
above 30 dB-Hz; reflections do sometimes). With ``--map minimum`` no building has a height (a map
without heights: :data:`~gnss_citygml.calibrate.shadows.MIN_WALL`).

The walked districts of ``scenes.py --regimes --regime district`` (each person their own
phone) with phone fixes; per scene the error of the fixes (per axis, RMS) across and along
the street each person walks, as reported and as matched. Also the floor of one shift per
window: what the window's mean error leaves. ``scenes.py --match known`` estimates the heights
from positions matched this way (the floor of shadow matching); ``scenes.py --calibrate
--calibration-matching shadows`` the package's, against the heights being estimated.

    python benchmarks/shadow_matching.py [--scenes 3] [--window 5] [--map known|minimum]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import pandas as pd

from gnss_citygml.calibrate.shadows import label_chances, shadow_offsets
from gnss_citygml.recordings import recording_windows

#: C/N0 taken as "arrives strong" (dB-Hz), and the chances of a strong (or, with ``los``, an
#: in-sight) signal for a ray the map leaves open and for one it blocks (reflections do arrive
#: strong sometimes).
STRONG = 30.0
P_SEEN = {"cn0": (0.85, 0.3), "los": (0.95, 0.05)}
RANGE = 300.0  # m of ray


def shadow_matched(
    obs: pd.DataFrame, footprints, heights=None, window: float = 10.0, labels: str = "cn0"
) -> pd.DataFrame:
    """``obs`` with its fixes (``e``, ``n``) moved by one shift per ``window`` seconds of each
    recording (:func:`gnss_citygml.calibrate.shadows.shadow_offsets`, each window's prior its
    median ``position_sd``); ``heights`` (absolute, as ``z``, one per footprint, NaN where
    unknown) or ``None``."""
    footprints = np.asarray(footprints)
    unit = recording_windows(obs, window)
    n_units = int(unit.max()) + 1
    sd = obs["position_sd"].groupby(unit).median().reindex(range(n_units)).fillna(3.0)
    rays = {
        "e": obs["e"].to_numpy(float),
        "n": obs["n"].to_numpy(float),
        "z": obs["z"].to_numpy(float),
        "bearing": obs["azimuth"].to_numpy(float),
        "tan_el": np.tan(np.radians(obs["elevation"].to_numpy(float))),
        "satellite": obs.groupby(["constellation", "svid"]).ngroup().to_numpy(),
    }
    seen = (obs["los"] if labels == "los" else obs["cn0"].fillna(0.0) >= STRONG).to_numpy()
    heights = np.full(len(footprints), np.nan) if heights is None else np.asarray(heights, float)
    offsets = shadow_offsets(
        rays, label_chances(seen, P_SEEN[labels]), unit, sd.to_numpy(), footprints, heights, RANGE
    )
    return obs.assign(e=obs["e"] + offsets[unit, 0], n=obs["n"] + offsets[unit, 1])


def _errors(obs, matched, window):
    """RMS per axis across and along each walker's street, and the floor of one shift per
    window (the error left once each window's mean is taken away)."""
    fixes = matched.drop_duplicates(["receiver", "time_utc"])
    north_south = fixes["receiver"].str.rsplit("_", n=1).str[1].astype(int) % 2 == 1
    de, dn = fixes["e"] - fixes["e_true"], fixes["n"] - fixes["n_true"]
    across, along = np.where(north_south, de, dn), np.where(north_south, dn, de)
    unit = recording_windows(fixes, window)
    mean_e, mean_n = (d.groupby(unit).transform("mean") for d in (de, dn))
    left = np.hypot(de - mean_e, dn - mean_n)
    rms = [float(np.sqrt(np.mean(np.square(v)))) for v in (across, along)]
    return (*rms, float(np.sqrt(np.mean(left**2) / 2)))


def main():
    from scenes import district_scene, phones, random_physics

    from gnss_citygml.simulate import simulate

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=3)
    parser.add_argument("--window", type=float, default=5.0, help="seconds of one shift")
    parser.add_argument("--map", choices=("known", "minimum"), default="known")
    parser.add_argument("--labels", choices=tuple(P_SEEN), default="cn0")
    args = parser.parse_args()
    print(
        "| scene | reported: across, along | matched: across, along | floor of one shift "
        "per window | seconds |\n|---|---|---|---|---|"
    )
    for k in range(args.scenes):
        scene, start, layout = district_scene(k)
        physics = phones(k, random_physics(k), len(scene.sessions))
        sim = simulate(scene, locations="gnss", seed=k, start=start, physics=physics)
        obs = sim.observations
        heights = None
        if args.map == "known":
            heights = sim.truth.set_index("id")["height"].reindex(sim.buildings["id"])
        began = time.perf_counter()
        matched = shadow_matched(obs, sim.buildings.geometry, heights, args.window, args.labels)
        seconds = time.perf_counter() - began
        before = _errors(obs, obs, args.window)
        after = _errors(obs, matched, args.window)
        print(
            f"| {k} ({layout}) | {before[0]:.2f}, {before[1]:.2f} m | {after[0]:.2f}, "
            f"{after[1]:.2f} m | {before[2]:.2f} m | {seconds:.0f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
