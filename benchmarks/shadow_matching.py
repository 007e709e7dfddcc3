"""How much of the phones' fix errors can shadow matching take back? (issue 28, a floor)

For each window of a recording, one horizontal shift of its fixes is chosen on a grid of
candidates within 2.5 reported standard deviations: the one whose rays best explain which
signals arrive strong (C/N0 at or above 30 dB-Hz) and which do not, against the footprints,
with a Gaussian prior on the shift and no fix inside a building. With ``--map known`` the
footprints carry the scene's true heights (a perfect map: the floor of map matching); with
``--map minimum`` only a minimum building height (what a map without heights says: a ray
crossing no footprint is open, one entering a wall below that height is blocked).

The walked districts of ``scenes.py --regimes --regime district`` (each person their own
phone) with phone fixes; per scene the error of the fixes (per axis, RMS) across and along
the street each person walks, as reported and as matched. Also the floor of one shift per
window: what the window's mean error leaves.

    python benchmarks/shadow_matching.py [--scenes 3] [--window 5] [--map known|minimum]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import shapely
from scenes import district_scene, phones, random_physics

from gnss_citygml.raycast import footprint_entries
from gnss_citygml.recordings import recording_windows
from gnss_citygml.simulate import simulate

#: Antenna above the ground (m), C/N0 taken as "arrives strong" (dB-Hz), the minimum building
#: height of ``--map minimum`` (m), and the chances of a strong signal for an open and a
#: blocked ray (reflections arrive strong sometimes).
ANTENNA, STRONG, MIN_HEIGHT = 1.1, 30.0, 5.0
P_STRONG = {"open": 0.85, "blocked": 0.3}
GRID = 13  # candidates per axis
RANGE = 300.0  # m of ray


def shadow_matched(obs, footprints, window, heights=None):
    """The fixes (``e``, ``n``) moved by one shift per ``window`` seconds of each recording."""
    unit = recording_windows(obs, window)
    shift = np.zeros((unit.max() + 1, 2))
    tree = shapely.STRtree(footprints)
    for k in range(unit.max() + 1):
        g = obs[unit == k]
        sd = float(np.nanmedian(g["position_sd"])) if g["position_sd"].notna().any() else 3.0
        steps = np.linspace(-min(2.5 * sd, 25.0), min(2.5 * sd, 25.0), GRID)
        sx, sy = (a.ravel() for a in np.meshgrid(steps, steps))
        x = (g["e"].to_numpy()[None, :] + sx[:, None]).ravel()
        y = (g["n"].to_numpy()[None, :] + sy[:, None]).ravel()
        elevation = np.tile(g["elevation"].to_numpy(), sx.size)
        ray, part, dist, _ = footprint_entries(
            x, y, np.tile(g["azimuth"].to_numpy(), sx.size), footprints, RANGE
        )
        rise = ANTENNA + dist * np.tan(np.radians(elevation[ray]))
        tops = np.full(part.size, MIN_HEIGHT) if heights is None else heights[part]
        blocked = np.zeros(x.size, bool)
        blocked[ray[tops > rise]] = True
        known = blocked | ~np.isin(np.arange(x.size), ray) if heights is None else True
        strong = np.tile(g["cn0"].fillna(0.0).to_numpy() >= STRONG, sx.size)
        p = np.where(blocked, P_STRONG["blocked"], P_STRONG["open"])
        loglik = np.where(known, np.log(np.where(strong, p, 1.0 - p)), 0.0)
        score = loglik.reshape(sx.size, -1).sum(axis=1) - 0.5 * (sx**2 + sy**2) / sd**2
        fixes = g.drop_duplicates("time_utc")
        points = shapely.points(
            (fixes["e"].to_numpy()[None, :] + sx[:, None]).ravel(),
            (fixes["n"].to_numpy()[None, :] + sy[:, None]).ravel(),
        )
        inside = np.zeros(points.size, bool)
        inside[tree.query(points, predicate="within")[0]] = True
        score -= 50.0 * inside.reshape(sx.size, -1).mean(axis=1)
        best = int(np.argmax(score))
        shift[k] = sx[best], sy[best]
    return obs["e"] + shift[unit, 0], obs["n"] + shift[unit, 1]


def _errors(obs, e, n, window):
    """RMS per axis across and along each walker's street, and the floor of one shift per
    window (the error left once each window's mean is taken away)."""
    fixes = obs.assign(e=e, n=n).drop_duplicates(["receiver", "time_utc"])
    north_south = fixes["receiver"].str.rsplit("_", n=1).str[1].astype(int) % 2 == 1
    de, dn = fixes["e"] - fixes["e_true"], fixes["n"] - fixes["n_true"]
    across, along = np.where(north_south, de, dn), np.where(north_south, dn, de)
    unit = recording_windows(fixes, window)
    mean_e, mean_n = (d.groupby(unit).transform("mean") for d in (de, dn))
    left = np.hypot(de - mean_e, dn - mean_n)
    rms = [float(np.sqrt(np.mean(np.square(v)))) for v in (across, along)]
    return (*rms, float(np.sqrt(np.mean(left**2) / 2)))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=3)
    parser.add_argument("--window", type=float, default=5.0, help="seconds of one shift")
    parser.add_argument("--map", choices=("known", "minimum"), default="known")
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
            truth = sim.truth.set_index("id").reindex(sim.buildings["id"])
            heights = (truth["height"] - truth["ground"]).to_numpy()
        began = time.perf_counter()
        e, n = shadow_matched(obs, np.asarray(sim.buildings.geometry), args.window, heights)
        seconds = time.perf_counter() - began
        before = _errors(obs, obs["e"], obs["n"], args.window)
        after = _errors(obs, e, n, args.window)
        print(
            f"| {k} ({layout}) | {before[0]:.2f}, {before[1]:.2f} m | {after[0]:.2f}, "
            f"{after[1]:.2f} m | {before[2]:.2f} m | {seconds:.0f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
