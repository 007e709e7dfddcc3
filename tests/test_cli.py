import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from gnss_citygml.cli import main


def run(args, capsys):
    with pytest.raises(SystemExit) as exc:
        main(args)
    out = capsys.readouterr()
    return exc.value.code, out.out, out.err


def test_simulate_then_heights(tmp_path, capsys):
    code, out, _ = run(["simulate", "hermitage", "-o", str(tmp_path), "--interval", "30"], capsys)
    assert code == 0 and "intersections" in out
    for name in ("observations", "intersections", "truth"):
        assert (tmp_path / f"{name}.csv").is_file()
    heights = tmp_path / "heights.csv"
    code, out, _ = run(["heights", str(tmp_path / "intersections.csv"), "-o", str(heights)], capsys)
    assert code == 0 and "converged" in out
    table = pd.read_csv(heights)
    assert "hermitage_terrace" in set(table["id"])
    assert not list(tmp_path.glob("*.part"))


def test_user_errors_are_one_line_with_exit_code_2(tmp_path, capsys):
    code, _, err = run(
        ["heights", str(tmp_path / "nope.csv"), "-o", str(tmp_path / "h.csv")], capsys
    )
    assert code == 2
    assert err.strip() == f"error: file not found ({tmp_path / 'nope.csv'}): check the path"
    bad = tmp_path / "bad.csv"
    pd.DataFrame({"building": ["a"], "height": [3.0]}).to_csv(bad, index=False)
    code, _, err = run(["heights", str(bad), "-o", str(tmp_path / "h.csv")], capsys)
    assert code == 2 and err.startswith("error: missing column(s) 'cn0'")
    assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "h.csv").exists()


def test_unknown_output_format_writes_nothing(tmp_path, capsys):
    run(["simulate", "ucl", "-o", str(tmp_path), "--interval", "120"], capsys)
    code, _, err = run(
        ["heights", str(tmp_path / "intersections.csv"), "-o", str(tmp_path / "h.xlsx")], capsys
    )
    assert code == 2 and "unknown table format '.xlsx'" in err
    assert not (tmp_path / "h.xlsx").exists()


@pytest.mark.parametrize("command", [["-m", "gnss_citygml"], ["console-script"]])
def test_entry_points_report_the_version(command):
    if command == ["console-script"]:
        argv = [str(Path(sys.executable).parent / "gnss-citygml")]
    else:
        argv = [sys.executable, *command]
    out = subprocess.run([*argv, "--version"], capture_output=True, text=True, check=True)
    assert out.stdout.startswith("gnss-citygml, version")
