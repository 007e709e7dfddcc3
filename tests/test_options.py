"""Each option a user chooses is declared once (gnss_citygml.options): the command line's
options are made from the declarations, whose defaults are the settings objects' and whose
ranges are those the settings' checks enforce (the QGIS side: qgis_plugin/tests)."""

import click
import pytest

from gnss_citygml.cli import COMMANDS, UTF8_TEXT, cli
from gnss_citygml.errors import InputError
from gnss_citygml.options import OPTIONS, SETTINGS, Option, settings_arguments
from gnss_citygml.settings import Estimator, PositionError, Rays


def command_options():
    """(command, click option) for every option of every subcommand."""
    context = click.Context(cli)
    for name in COMMANDS:
        command = cli.get_command(context, name)
        for param in command.params:
            if isinstance(param, click.Option):
                yield name, param


def test_every_command_line_option_of_a_setting_is_its_declaration():
    seen = set()
    for command, param in command_options():
        spec = next((s for s in OPTIONS.values() if s.dest == param.name), None)
        if spec is None:
            continue
        seen.add(spec.name)
        where = f"{command} {spec.flag}"
        assert param.default == spec.default, where
        assert param.help == spec.help, where
        assert spec.flag in param.opts, where
        if spec.kind == "choice":
            assert list(param.type.choices) == list(spec.choices), where
        elif spec.kind == "switch":
            assert param.is_flag and param.secondary_opts, where
        elif spec.kind == "field":
            assert param.type is UTF8_TEXT, where  # text: refused if not UTF-8
        elif spec.kind == "count":
            assert param.type is click.INT, where
        else:
            assert param.type is click.FLOAT, where
    assert seen == set(OPTIONS)  # every declaration is offered by some command


@pytest.mark.parametrize("spec", OPTIONS.values(), ids=list(OPTIONS))
def test_the_default_is_the_settings_objects(spec):
    settings, field = spec.setting
    assert getattr(SETTINGS[settings](), field) == spec.default


@pytest.mark.parametrize(
    "spec", [s for s in OPTIONS.values() if s.kind in ("number", "count")], ids=lambda s: s.name
)
def test_the_range_is_the_one_the_settings_enforce(spec):
    settings, field = spec.setting
    low, high = spec.bounds
    step = 1 if spec.kind == "count" else 1.0  # a count's ends are whole numbers
    for outside in (low - step, high + step):
        with pytest.raises(InputError):
            make(settings, field, outside)
    make(settings, field, low if field == "min_elevation" else high)  # an end is in


def make(settings, field, value):
    """The settings object with ``field`` at ``value``, the rest default (a calibration window
    needs a prior)."""
    extra = {"prior_sd": 5.0} if (settings, field) == ("calibration", "window") else {}
    return SETTINGS[settings](**{field: value, **extra})


def test_the_elevation_bounds_are_the_masks():
    Rays(min_elevation=-90.0, max_elevation=90.0)  # the widest band: QGIS allows it too
    assert OPTIONS["MIN_ELEVATION"].bounds == OPTIONS["MAX_ELEVATION"].bounds == (-90.0, 90.0)


def test_settings_arguments_leave_out_what_is_not_given():
    values = {"POSITION_SD": None, "POSITION_DISTANCE": 50.0, "METHOD": "4PL"}
    assert settings_arguments(values, list(values)) == {
        "position_error": {"distance": 50.0},
        "estimator": {"method": "4PL"},
    }


def test_a_declaration_is_checked():
    with pytest.raises(ValueError, match="kind"):
        Option(("rays", "x"), "--x", "text", "X", "X.")
    with pytest.raises(ValueError, match="choices"):
        Option(("estimator", "method"), "--method", "choice", "Method", "Method.")
    assert Option(("rays", "max_range"), "--max-range", "number", "R", "R.").name == "MAX_RANGE"


def test_a_commands_options_become_the_settings_objects():
    from gnss_citygml.cli.options import chosen_settings

    chosen = {"min_elevation": 15.0, "method": "4PL", "position_sd": None, "quiet": True}
    settings = chosen_settings(chosen)
    assert chosen == {"quiet": True}  # what is not a setting stays for the command
    assert settings["rays"] == Rays(min_elevation=15.0)
    assert settings["estimator"] == Estimator(method="4PL")
    assert settings["position_error"] == PositionError()
    assert set(settings) == {"rays", "estimator", "position_error"}


def test_the_caps_of_the_fits_are_options_of_every_command_that_fits(tmp_path, capsys):
    """``--max-iter`` and ``--fit-max-iter`` reach the estimator: whole numbers in their
    ranges, refused in one line outside them or as fractions."""
    from test_cli import run

    from gnss_citygml.cli.options import chosen_settings

    for command in ("estimate", "report", "update", "heights"):
        flags = {p.opts[0] for _, p in command_options() if _ == command}
        assert {"--max-iter", "--fit-max-iter"} <= flags, command
    chosen = {"max_iter": 100, "fit_max_iter": 2000}
    assert chosen_settings(chosen)["estimator"] == Estimator(max_iter=100, fit_max_iter=2000)
    table = tmp_path / "in.csv"
    table.write_text("building,height,cn0\na,10,\na,30,40\n")
    out = tmp_path / "out.csv"
    for flags, message in (
        (["--fit-max-iter", "0"], "fit_max_iter must be a whole number, 1 to 10000, not 0"),
        (["--max-iter", "1001"], "max_iter must be a whole number, 1 to 1000, not 1001"),
        (["--fit-max-iter", "2.5"], "'2.5' is not a valid integer"),
    ):
        code, _, err = run(["heights", str(table), "-o", str(out), *flags], capsys)
        assert code == 2 and message in err, err
        assert not out.exists()
