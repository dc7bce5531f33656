"""Every command of the README's Usage block runs (in a scratch folder that sees
sample_data/ and tests/data/ as the repository root does)."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest
from click.testing import CliRunner

from evperc.cli import cli

ROOT = Path(__file__).resolve().parents[1]


def usage_commands() -> list[str]:
    text = (ROOT / "README.md").read_text()
    block = text.split("## Usage", 1)[1].split("```sh", 1)[1].split("```", 1)[0]
    return [line.strip() for line in block.splitlines()
            if line.strip() and not line.strip().startswith("#")]


def test_readme_opens_with_the_two_make_targets() -> None:
    head = (ROOT / "README.md").read_text().split("\n## ", 1)[0]
    first_commands = re.findall(r"^make (\w+)", head, flags=re.M)
    assert first_commands[:2] == ["run", "test"]


def test_every_usage_command_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "sample_data").symlink_to(ROOT / "sample_data")
    (tmp_path / "tests").mkdir()
    (tmp_path / "tests" / "data").symlink_to(ROOT / "tests" / "data")
    monkeypatch.chdir(tmp_path)
    commands = usage_commands()
    assert len(commands) >= 9
    for command in commands:
        words = shlex.split(command)
        assert words[0] == "evperc", command
        result = CliRunner().invoke(cli, words[1:])
        assert result.exit_code == 0, f"{command}\n{result.output}"


@pytest.mark.slow
def test_make_run_can_be_run_twice(tmp_path: Path) -> None:
    """`make run` is the README's first command: running it again over its own output works
    (the render of the second run replaces the first one's pictures)."""
    import shutil
    import subprocess
    import sys

    make = shutil.which("make")
    if make is None:
        pytest.skip("make is not installed")
    bin_dir = Path(sys.executable).parent
    out = tmp_path / "out"
    # -o: take the installed package as is (this test runs inside the installed venv)
    cmd = [make, "-C", str(ROOT), "run", "-o", ".venv/.installed", f"BIN={bin_dir}",
           f"OUT={out}"]
    for _ in range(2):
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stdout + done.stderr
    assert (out / "sample.gif").is_file()
    assert len(list((out / "sample-png").glob("*.png"))) == 200
