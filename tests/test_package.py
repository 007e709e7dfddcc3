"""The package as users meet it: the public API at the top level, its version, and a command
line that lists its commands without loading the pipeline's stages."""

import ast
import contextlib
import inspect
import json
import pkgutil
import subprocess
import sys
from importlib import import_module, metadata, resources
from pathlib import Path

import click
import pytest

import gnss_citygml
from gnss_citygml import cli as cli_package
from gnss_citygml.cli import COMMANDS, cli, main

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "city"

#: What the command line must not load to print its version or its list of commands.
HEAVY = ("numpy", "pandas", "scipy", "geopandas", "pyproj", "rasterio", "pyogrio", "shapely")
SIMULATOR = "gnss_citygml.simulate"

# --- the public API -------------------------------------------------------------------------


@pytest.mark.parametrize("name", gnss_citygml.__all__)
def test_public_names_resolve(name):
    assert getattr(gnss_citygml, name) is not None


def test_unknown_name():
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        gnss_citygml.nope  # noqa: B018


def test_all_is_the_eager_and_the_lazy_names():
    eager = {"GnssCityGMLError", "InputError", "MissingColumnError", "ModelError", "__version__"}
    assert len(set(gnss_citygml.__all__)) == len(gnss_citygml.__all__)
    assert set(gnss_citygml.__all__) == eager | set(gnss_citygml._LAZY)
    for name in ("estimate", "estimate_heights", "read_observations", "read_footprints"):
        assert name in gnss_citygml.__all__
    assert gnss_citygml.estimate.__module__ == "gnss_citygml.pipeline"
    assert gnss_citygml.estimate_heights.__module__ == "gnss_citygml.model.estimate"


def test_type_checkers_see_the_lazy_names():
    """The ``if TYPE_CHECKING`` imports of ``__init__.py`` are the :data:`_LAZY` map itself."""
    tree = ast.parse(Path(gnss_citygml.__file__).read_text())
    block = next(n for n in tree.body if isinstance(n, ast.If) and "TYPE_CHECKING" in ast.dump(n))
    imported = {
        alias.name: node.module
        for node in block.body
        if isinstance(node, ast.ImportFrom)
        for alias in node.names
    }
    assert imported == gnss_citygml._LAZY


def test_version_comes_from_the_metadata():
    assert gnss_citygml.__version__ == metadata.version("gnss-citygml")
    assert "__version__ =" not in Path(gnss_citygml.__file__).read_text()


def test_the_package_says_it_is_typed():
    assert resources.files("gnss_citygml").joinpath("py.typed").is_file()


def _modules():
    """The package and every module in it (``__main__`` would run the command)."""
    yield gnss_citygml
    for info in pkgutil.walk_packages(gnss_citygml.__path__, "gnss_citygml."):
        if info.name != "gnss_citygml.__main__":
            yield import_module(info.name)


def _public_functions():
    """(name, function) of every function a module lists in its ``__all__`` and of the public
    methods (and ``__init__``) of every class it lists, each where it is defined."""
    for module in _modules():
        for name in getattr(module, "__all__", ()):
            value = getattr(module, name)
            if getattr(value, "__module__", None) != module.__name__:
                continue  # re-exported: checked where it is defined
            if inspect.isfunction(value):
                yield f"{module.__name__}.{name}", value
            elif inspect.isclass(value):
                for attr, member in vars(value).items():
                    member = getattr(member, "__func__", getattr(member, "fget", member))
                    if attr == "__init__" and getattr(value, "_is_protocol", False):
                        continue  # typing.Protocol's own, not the module's
                    if inspect.isfunction(member) and (attr == "__init__" or attr[0] != "_"):
                        yield f"{module.__name__}.{name}.{attr}", member


def _unannotated(function) -> list[str]:
    """The parameters of ``function`` without a type annotation, and ``return`` if its result
    has none (``__init__`` returns None by definition)."""
    signature = inspect.signature(function)
    missing = [
        p.name
        for p in signature.parameters.values()
        if p.annotation is inspect.Parameter.empty and p.name not in ("self", "cls")
    ]
    if signature.return_annotation is inspect.Signature.empty and function.__name__ != "__init__":
        missing.append("return")
    return missing


def test_unannotated_finds_what_lacks_a_type():
    def half(x: int, y, *args, scale: float = 1.0, **kw) -> float: ...

    def whole(self, x: int): ...

    assert _unannotated(half) == ["y", "args", "kw"]
    assert _unannotated(whole) == ["return"]
    assert _unannotated(gnss_citygml.InputError.__init__) == []


def test_public_signatures_are_typed():
    """Every public function and method has its parameters and result annotated: mypy (in
    ``make lint``) checks the calls of users who type-check their code against them."""
    functions = dict(_public_functions())
    assert "gnss_citygml.gnss.orbits.Orbits.positions" in functions and len(functions) > 150
    missing = {name: gaps for name, f in functions.items() if (gaps := _unannotated(f))}
    assert not missing, "\n".join(f"{name}: {', '.join(gaps)}" for name, gaps in missing.items())


# --- the job with GeoDataFrames in and out --------------------------------------------------


@pytest.fixture(scope="module")
def city():
    return (
        gnss_citygml.read_observations(EXAMPLE / "observations.parquet"),
        gnss_citygml.read_footprints(EXAMPLE / "footprints.gpkg"),
        str(EXAMPLE / "dem.tif"),
    )


def test_the_job_from_the_top_level(city, grid_dir, tmp_path):
    observations, footprints, dem = city
    heights = gnss_citygml.estimate(observations, footprints, dem, grid_dir=grid_dir)
    assert heights.crs.to_epsg() == 27700 and len(heights) == len(footprints)
    converged = int(heights["converged"].sum())
    assert converged >= 22
    for write, name in [
        (gnss_citygml.write_cityjson, "city.city.json"),
        (gnss_citygml.write_citygml, "city.gml"),
    ]:
        result = write(heights, tmp_path / name)
        assert result.written == converged and result.report.valid
        assert gnss_citygml.validate_file(tmp_path / name).valid
    model = json.loads((tmp_path / "city.city.json").read_text())
    assert sum(o["type"] == "Building" for o in model["CityObjects"].values()) == converged


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (
            lambda fp: fp.to_crs("EPSG:4326"),
            "the footprints are in WGS 84 (EPSG:4326), not EPSG:27700 (British National Grid) "
            "(footprints): read the file with read_footprints(path), which converts them with "
            "OSTN15",
        ),
        (
            lambda fp: fp.set_crs(None, allow_override=True),
            "the footprints have no CRS (footprints): read the file with read_footprints(path), "
            "or set the CRS",
        ),
        (
            lambda fp: str(EXAMPLE / "footprints.gpkg"),
            "the footprints must be a GeoDataFrame, not str (footprints): read them with "
            "read_footprints(path)",
        ),
    ],
    ids=["wgs84", "no-crs", "a-path"],
)
def test_footprints_not_in_bng_are_one_clear_error(city, change, message):
    observations, footprints, dem = city
    with pytest.raises(gnss_citygml.InputError) as exc:
        gnss_citygml.estimate(observations, change(footprints), dem)
    assert exc.value.one_line().startswith(message)
    assert "\n" not in exc.value.one_line()


# --- the command line -----------------------------------------------------------------------


def _defined_commands():
    """Every click command the modules of ``gnss_citygml.cli`` define, by name."""
    found = {}
    for info in pkgutil.iter_modules(cli_package.__path__):
        module = import_module(f"{cli_package.__name__}.{info.name}")
        for value in vars(module).values():
            if isinstance(value, click.Command) and value.callback.__module__ == module.__name__:
                found[value.name] = info.name
    return found


def test_the_listed_commands_are_the_defined_ones():
    """A command written in a module but missing from ``COMMANDS``, or listed in the wrong
    module, fails here: the help and the commands cannot drift apart."""
    assert _defined_commands() == {name: module for name, (module, _) in COMMANDS.items()}
    for name, (_, short_help) in COMMANDS.items():
        assert cli.get_command(None, name).get_short_help_str(10**6) == short_help


@pytest.mark.parametrize("width", [60, 80, 200])
def test_help_lists_the_commands_as_click_would(width):
    """The group's list of commands, written from the table, is the one click writes from the
    loaded commands, at any terminal width."""
    ctx = click.Context(cli, info_name="gnss-citygml", terminal_width=width)
    lazy, loaded = ctx.make_formatter(), ctx.make_formatter()
    cli.format_commands(ctx, lazy)
    click.Group.format_commands(cli, ctx, loaded)
    assert lazy.getvalue() == loaded.getvalue()
    assert sorted(COMMANDS) == [line.split()[0] for line in lazy.getvalue().splitlines()[1:]]


def test_unknown_command(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["nope"])
    assert exc.value.code == 2 and "No such command 'nope'" in capsys.readouterr().err


_LOADED = """
import contextlib, io, json, sys
from gnss_citygml.cli import main
with contextlib.redirect_stdout(io.StringIO()) as out, contextlib.suppress(SystemExit):
    main(sys.argv[1:])
print(json.dumps({"out": out.getvalue(), "modules": sorted(sys.modules)}))
"""


def _loaded(*args):
    """The output and the modules loaded by ``gnss-citygml ARGS`` in a fresh interpreter."""
    run = subprocess.run(
        [sys.executable, "-c", _LOADED, *args], capture_output=True, text=True, check=True
    )
    return json.loads(run.stdout)


@pytest.mark.parametrize("args", [["--version"], ["--help"]])
def test_version_and_help_load_no_stage(args):
    """An import check, not a timing: pandas, scipy, GDAL, PROJ and the simulator take over a
    second to load, and neither the version nor the list of commands needs them."""
    result = _loaded(*args)
    assert result["out"].startswith("gnss-citygml, version" if args == ["--version"] else "Usage")
    loaded = [
        name
        for name in result["modules"]
        if name.split(".")[0] in HEAVY or name.startswith(SIMULATOR)
    ]
    assert loaded == []


def test_import_loads_no_stage():
    code = "import sys, gnss_citygml; print(' '.join(sys.modules))"
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert not {name.split(".")[0] for name in run.stdout.split()} & set(HEAVY)


@pytest.mark.parametrize("command", ["estimate", "heights"])
def test_a_subcommand_help_loads_only_its_module(command):
    """Only ``simulate`` loads the simulator: the commands of the job do not."""
    result = _loaded(command, "--help")
    assert "--method [4PL-B|4PL|hinge|bayes]" in result["out"]
    assert f"{cli_package.__name__}.{command}" in result["modules"]
    assert f"{cli_package.__name__}.simulate" not in result["modules"]
    assert not any(name.startswith(SIMULATOR) for name in result["modules"])


def test_version_printed_by_the_command(capsys):
    with contextlib.suppress(SystemExit):
        main(["--version"])
    assert capsys.readouterr().out == f"gnss-citygml, version {gnss_citygml.__version__}\n"


def test_the_readme_stays_a_users_guide():
    """At most 400 lines (issue 29): measurements and details live in docs/, linked from it."""
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text(encoding="utf-8")
    assert len(readme.splitlines()) <= 400, "move details into docs/ and link them"
