import numpy as np
import pandas as pd
import pytest

from gnss_citygml import InputError
from gnss_citygml.simulate import PRESETS, simulate
from gnss_citygml.simulate.constellations import satellite_ecef, sky
from gnss_citygml.simulate.signals import SignalModel, diffraction_loss

OBS_COLUMNS = {
    "time_utc",
    "receiver",
    "constellation",
    "svid",
    "azimuth",
    "elevation",
    "cn0",
    "e",
    "n",
    "z",
}
INTER_COLUMNS = {"signal", "building", "height", "distance", "order", "cn0"}


@pytest.fixture(scope="module")
def sims():
    return {
        (p, loc): simulate(p, locations=loc, seed=1, interval=15.0)
        for p in PRESETS
        for loc in ("manual", "gnss")
    }


def test_tables_follow_the_design(sims):
    for sim in sims.values():
        assert OBS_COLUMNS <= set(sim.observations.columns)
        assert INTER_COLUMNS <= set(sim.intersections.columns)
        assert isinstance(sim.observations["time_utc"].dtype, pd.DatetimeTZDtype)
        assert set(sim.observations["constellation"]) == {"G", "R", "E", "C"}
        assert sim.truth["target"].any()


def test_intersection_heights_follow_the_rays(sims):
    sim = sims[("ucl", "manual")]
    o, i = sim.observations, sim.intersections
    expected = o["z"].to_numpy()[i["signal"]] + i["distance"] * np.tan(
        np.radians(o["elevation"].to_numpy()[i["signal"]])
    )
    np.testing.assert_allclose(i["height"], expected)
    assert (i.groupby("signal")["order"].min() == 0).all()


def test_every_signal_is_within_the_mask(sims):
    for (_preset, _), sim in sims.items():
        el = sim.observations["elevation"]
        assert el.min() >= sim.scene.min_elevation and el.max() <= sim.scene.max_elevation


def test_phone_sees_30_to_50_satellites():
    _, _, xyz = satellite_ecef(np.arange(0.0, 86400.0, 900.0))
    _, el = sky(51.52, -0.13, 70.0, xyz)
    visible = (el > 0).sum(axis=1)
    assert 30 <= visible.mean() <= 50


def test_sites_differ_as_the_papers_do(sims):
    def los(preset):
        return sims[(preset, "manual")].observations["los"].mean()

    assert los("goodchild") < 0.4  # a canyon: most signals blocked
    assert los("ucl") > 0.5  # an open square


def test_cn0_distributions_overlap_but_separate(sims):
    o = pd.concat([s.observations for s in sims.values()])
    los, nlos = o.loc[o["los"], "cn0"].dropna(), o.loc[~o["los"], "cn0"].dropna()
    assert los.mean() - nlos.mean() > 8.0
    assert (nlos > los.quantile(0.1)).mean() > 0.02  # some NLOS look like LOS
    assert o["cn0"].min() >= SignalModel.tracking_threshold
    assert o["cn0"].isna().any()  # blocked signals exist


def test_diffraction_loss_is_itu_knife_edge():
    assert diffraction_loss(0.0, 50.0, 30.0) == pytest.approx(6.0, abs=0.1)  # grazing: 6 dB
    assert diffraction_loss(-50.0, 50.0, 30.0) == 0.0
    assert diffraction_loss(2.0, 10.0, 30.0) > diffraction_loss(0.5, 10.0, 30.0) > 6.0
    # v = 1 m x sqrt(2 / (0.1903 m x 10 m)) = 1.025 at the horizon: J(v) = 14.0 dB
    assert diffraction_loss(1.0, 10.0, 0.0) == pytest.approx(14.0, abs=0.1)
    # a steep ray 1 m below the edge is diffracted less than a low one
    assert diffraction_loss(1.0, 10.0, 70.0) < diffraction_loss(1.0, 10.0, 10.0)


def test_location_errors(sims):
    def err(preset, loc):
        o = sims[(preset, loc)].observations
        return np.hypot(o["e"] - o["e_true"], o["n"] - o["n_true"])

    for preset in PRESETS:
        assert err(preset, "manual").median() < 2.5
    assert err("goodchild", "gnss").median() > 3.0
    canyon = sims[("goodchild", "gnss")].observations
    across = np.abs(canyon["n"] - canyon["n_true"]).mean()  # the street runs east-west
    along = np.abs(canyon["e"] - canyon["e_true"]).mean()
    assert across > along


def test_seeds_reproduce_and_differ():
    a = simulate("hermitage", seed=5, interval=60.0)
    b = simulate("hermitage", seed=5, interval=60.0)
    c = simulate("hermitage", seed=6, interval=60.0)
    pd.testing.assert_frame_equal(a.observations, b.observations)
    assert not a.observations["cn0"].equals(c.observations["cn0"])


def test_bad_arguments():
    with pytest.raises(InputError, match="unknown simulator preset"):
        simulate("paris")
    with pytest.raises(InputError, match="unknown locations"):
        simulate("ucl", locations="psychic")


@pytest.mark.parametrize(
    "arguments, message",
    [
        ({"interval": 1e-9}, "--interval must be a number of seconds from 0.01 to 3600"),
        ({"interval": float("nan")}, "--interval .* not nan"),
        ({"interval": float("inf")}, "--interval"),
        ({"interval": -1.0}, "--interval"),
        ({"interval": 0.0}, "--interval"),
        ({"interval": 1e300}, "--interval"),
        # counts that would exhaust memory are refused from their size, before any work
        ({"interval": 0.02}, "417,500 epochs .* more than the 200,000 .* --interval 0.05 or more"),
        ({"seed": -1}, "the seed must be a whole number, 0 or more"),
        ({"seed": 1.5}, "the seed"),
        ({"max_range": float("nan")}, "max_range"),
        ({"max_range": 0.0}, "max_range"),
        ({"start": "yesterday-ish"}, "the start 'yesterday-ish' is not a UTC time"),
        ({"start": "1066-10-14"}, "not a UTC time from 1980-01-06"),
    ],
)
def test_numeric_arguments_are_checked_before_any_work(arguments, message):
    with pytest.raises(InputError, match=message) as caught:
        simulate("hermitage", **arguments)
    assert "\n" not in str(caught.value)


@pytest.mark.parametrize(
    "bad",
    [
        {"fading_sd": -1.0},
        {"zenith_cn0": float("nan")},
        {"reflected_open": 2.0},
        {"nlos_delay": -5.0},
        {"understatement": 0.0},
        {"reflection_seconds": -1.0},
        {"fix_seconds": float("inf")},
    ],
)
def test_a_signal_model_that_is_no_physics_is_refused(bad):
    with pytest.raises(InputError, match=f"signal model {next(iter(bad))}"):
        SignalModel(**bad)


def test_a_start_without_a_zone_is_utc():
    a = simulate("goodchild", interval=600.0, start="2020-02-11T10:00:00")
    b = simulate("goodchild", interval=600.0)
    pd.testing.assert_frame_equal(a.observations, b.observations)


def test_observations_carry_wgs84_positions_matching_the_grid(sims):
    o = sims[("ucl", "manual")].observations
    assert o["h"].isna().all()  # receiver heights come from the DEM, as in the paper
    # 1 m of northing is 1/111.2 km of latitude in London; 1 m of easting 1/69.3 km of longitude
    dlat = (o["lat"] - 51.5246) * 111_250.0
    dlon = (o["lon"] + 0.1340) * 111_320.0 * np.cos(np.radians(51.5246))
    np.testing.assert_allclose(dlat, o["n"], atol=0.5)
    np.testing.assert_allclose(dlon, o["e"], atol=0.5)


def test_start_time_moves_the_satellites():
    a = simulate("ucl", interval=120.0)
    b = simulate("ucl", interval=120.0, start="2024-06-01T15:00:00Z")
    assert b.observations["time_utc"].iloc[0] == pd.Timestamp("2024-06-01T15:00:00Z")
    assert not np.allclose(a.observations["azimuth"].iloc[:5], b.observations["azimuth"].iloc[:5])


def test_the_physics_can_be_changed_and_does_what_it_says():
    """Issue 14 judges the estimator across the physics: each knob moves what it names, and
    the defaults are the simulator's constants (the bundled sample city is unchanged)."""

    def run(**physics):
        sim = simulate("goodchild", interval=10.0, seed=3, physics=SignalModel(**physics))
        return sim.observations

    base = run()
    pd.testing.assert_frame_equal(base, simulate("goodchild", interval=10.0, seed=3).observations)
    weak, strong = run(reflection_loss=15.0), run(reflection_loss=3.0)
    blocked = ~base["los"]
    assert strong.loc[blocked, "cn0"].median() > weak.loc[blocked, "cn0"].median() + 6.0
    assert run(reflected_facade=0.0, reflected_open=0.0).loc[blocked, "cn0"].isna().mean() > (
        base.loc[blocked, "cn0"].isna().mean() + 0.2
    )
    assert run(tracking_threshold=20.0)["cn0"].min() >= 20.0
    assert run(body_loss=6.0)["cn0"].median() < base["cn0"].median() - 4.0
    off = run(manual_sd=0.0)
    assert np.allclose(off["e"], off["e_true"]) and not np.allclose(base["e"], base["e_true"])


def test_the_phones_fixes_can_be_made_as_harsh_as_real_streets():
    """Issue 48: the fixes' physics does what it says. Longer reflected paths put the fixes
    further off; a phone that understates claims exactly that many times less; reflections that
    last and a phone that smooths its fixes hold an error for longer. The defaults keep the
    simulator's fixes bit for bit."""
    from gnss_citygml.simulate.scenes import street_scene

    scene = street_scene(np.random.default_rng(8), 12.0, 4.0, walkers=2, walk_seconds=400.0)

    def fixes(**physics):
        sim = simulate(scene, locations="gnss", seed=4, physics=SignalModel(**physics))
        obs = sim.observations.drop_duplicates(["receiver", "time_utc"])
        return obs, (obs["e"] - obs["e_true"]).to_numpy(), (obs["n"] - obs["n_true"]).to_numpy()

    def rms(de, dn):
        return np.sqrt(np.mean(de**2 + dn**2))

    def steps(obs, de):  # the mean change of the east error from one epoch to the next
        receivers = obs.groupby("receiver").indices.values()
        return np.mean([np.abs(np.diff(de[rows])).mean() for rows in receivers])

    def flips(obs):  # how often a blocked signal's reception changes from one epoch to the next
        blocked = obs[~obs["los"]].sort_values("time_utc")
        received = blocked["cn0"].notna().astype(int)
        keys = [blocked[k] for k in ("receiver", "constellation", "svid")]
        return received.groupby(keys).diff().abs().mean()

    base, de, dn = fixes()
    same, _, _ = fixes(nlos_delay=15.0, understatement=1.0)
    pd.testing.assert_frame_equal(base, same)
    far, fe, fn = fixes(nlos_delay=60.0)
    assert rms(fe, fn) > 1.5 * rms(de, dn)
    claimed, ce, cn = fixes(understatement=2.0)
    np.testing.assert_allclose(claimed["position_sd"], base["position_sd"] / 2.0)
    np.testing.assert_array_equal(ce, de)
    smooth, se, _ = fixes(fix_seconds=10.0)
    assert steps(smooth, se) < steps(base, de) / 3.0
    # without fading, whether a blocked signal is received is whether it arrives reflected
    steady = {
        "fading_sd": 0.0,
        "reflection_sd": 0.0,
        "reflected_facade": 0.5,
        "reflected_open": 0.5,
    }
    anew = simulate(scene, seed=4, physics=SignalModel(**steady)).observations
    lasting = SignalModel(**steady, reflection_seconds=30.0)
    assert flips(simulate(scene, seed=4, physics=lasting).observations) < flips(anew) / 3.0


def test_another_day_walks_the_same_district_with_other_people():
    """Issue 48: walks on other days are another draw of walkers over the same grid, named as
    their own receivers; the district's own walks are city_scene's."""
    from gnss_citygml.simulate.scenes import city_scene, city_walks

    scene = city_scene(np.random.default_rng(2), 4, 3, walkers=5)
    again = np.random.default_rng(2)
    city_scene(again, 4, 3, walkers=0)  # the same buildings: the same draws before the walks
    assert city_walks(again, 4, 3, 5) == scene.sessions
    day2 = city_walks(np.random.default_rng(7), 4, 3, 6, name="day2_walker")
    assert [s.receiver for s in day2] == [f"day2_walker_{k}" for k in range(6)]
    assert {s.path for s in day2} != {s.path for s in scene.sessions}
    streets = {51.0 + 60.0 * k for k in range(4)}
    assert all(s.path[0][0] in streets or s.path[0][1] in streets for s in day2)


def test_each_session_may_have_its_own_phone():
    """Issue 27, decision 3: scenes where each recording is its own phone, so that per-device
    calibration can be judged: each session's physics is its own (here its tracking threshold
    and body loss, and the offset drawn from its own device_sd)."""
    from gnss_citygml.simulate.scenes import street_scene

    scene = street_scene(np.random.default_rng(5), 20.0, 6.0, walkers=3)
    quiet = SignalModel(device_sd=0.0, session_sd=0.0)
    phones = [
        quiet,
        SignalModel(device_sd=0.0, session_sd=0.0, body_loss=8.0),
        SignalModel(device_sd=0.0, session_sd=0.0, tracking_threshold=30.0),
    ]
    obs = simulate(scene, interval=20.0, seed=1, physics=phones).observations
    clear = obs[obs["los"]].groupby("receiver")["cn0"]
    first, body, picky = (scene.sessions[k].receiver for k in range(3))
    assert clear.median()[first] - clear.median()[body] == pytest.approx(8.0, abs=1.5)
    weakest = obs.groupby("receiver")["cn0"].min()
    assert weakest[picky] >= 30.0 > weakest[first]
    with pytest.raises(InputError, match=r"one per session \(3\), not 2 values"):
        simulate(scene, interval=20.0, physics=phones[:2])


def test_street_scene_has_the_width_and_offset_asked_for():
    from gnss_citygml.simulate.scenes import street_scene

    scene = street_scene(np.random.default_rng(5), 12.0, 4.0, walkers=2)
    south = [b for b in scene.buildings if b.id.startswith("street_s")]
    north = [b for b in scene.buildings if b.id.startswith("street_n")]
    assert len(south) == len(north) == 6
    assert max(b.footprint.bounds[3] for b in south) == pytest.approx(0.0)
    assert min(b.footprint.bounds[1] for b in north) == pytest.approx(12.0)
    assert {point[1] for s in scene.sessions for point in s.path} == {4.0}
    sim = simulate(scene, interval=20.0, seed=1)
    assert 0.0 < sim.observations["los"].mean() < 0.6  # a canyon: most signals blocked
    with pytest.raises(ValueError, match="inside the street"):
        street_scene(np.random.default_rng(5), 12.0, 15.0)


def test_the_roof_span_of_each_kind_of_building():
    """Issue 27: the truth's roof span is the roof's lowest and highest point, from the
    geometry: a flat roof's one height, a pitched roof's eaves and ridge (its strips' tops lie
    between), a multi-part building's lowest and highest part."""
    from shapely.geometry import box

    from gnss_citygml.simulate.scenes import flat, multipart, pitched

    one = flat("f", box(0, 0, 10, 10), 20.0, 12.0)
    assert one.roof_span == (32.0, 32.0) and one.true_height == 32.0
    roof = pitched("p", 0, 0, 30, 9, 20.0, 9.0, 11.0)
    assert roof.roof_span == (29.0, 31.0) and roof.true_height == 30.0
    tops = [top for _, top in roof.parts]
    assert 29.0 < min(tops) < max(tops) < 31.0
    stepped = multipart("m", [(box(0, 0, 10, 10), 12.0), (box(10, 0, 20, 10), 18.0)], 20.0)
    assert stepped.roof_span == (32.0, 38.0) and stepped.true_height == 35.0
    named = multipart("u", [(box(0, 0, 10, 10), 18.5), (box(10, 0, 20, 10), 32.0)], 26.0, 20.0)
    assert named.roof_span == (44.5, 58.0) and named.true_height == 46.0  # the part named


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_the_truth_table_has_the_roof_span(sims, preset):
    """Each building's span holds its true height; flat roofs have a span of one height,
    pitched and multi-part ones a span as wide as their roofs."""
    sim = sims[(preset, "manual")]
    truth = sim.truth.set_index("id")
    assert list(sim.truth.columns) == ["id", "height", "ground", "target", "roof_low", "roof_high"]
    assert (truth["roof_low"] <= truth["height"]).all()
    assert (truth["height"] <= truth["roof_high"]).all()
    for b in sim.scene.buildings:
        tops = [top for _, top in b.parts]
        low, high = truth.loc[b.id, ["roof_low", "roof_high"]]
        if len(tops) == 1:
            assert low == high == b.true_height
        elif b.span is None:  # multi-part: its lowest and highest part
            assert (low, high) == (min(tops), max(tops))
        else:  # pitched: eaves and ridge, beyond its strips' tops
            assert low < min(tops) and max(tops) < high
            assert (low + high) / 2 == pytest.approx(b.true_height)
    if preset == "ucl":
        assert tuple(truth.loc["ucl_main", ["roof_low", "roof_high"]]) == (44.5, 58.0)
    if preset == "hermitage":
        assert tuple(truth.loc["hermitage_terrace", ["roof_low", "roof_high"]]) == (33.0, 35.0)


def test_street_scenes_have_spans_for_their_setbacks():
    from gnss_citygml.simulate.scenes import street_scene

    scene = street_scene(np.random.default_rng(3), 12.0, 4.0)
    widths = {round(b.roof_span[1] - b.roof_span[0], 6) for b in scene.buildings}
    assert 0.0 in widths and (6.0 in widths or 3.0 in widths)
    for b in scene.buildings:
        assert b.roof_span[0] <= b.true_height <= b.roof_span[1]
