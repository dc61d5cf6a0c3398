"""The demo runs step by step, refuses to reuse a folder unasked and says which step is unknown."""

from __future__ import annotations

from pathlib import Path

from tensegrity_env.model import Model
from tensegrity_sr.demo import STEPS, Demo, main


def test_first_steps_run_and_a_rerun_needs_force(tmp_path: Path, one_line_error) -> None:
    out = tmp_path / "demo"
    assert main(["--out", str(out), "--steps", "generate,identify"]) == 0
    model = Model.load(out / "params.json")
    assert model.topology.n_rods == 6 and float(model.params.mass.min()) > 0
    assert main(["--out", str(out), "--steps", "generate"]) == 2
    one_line_error(f"--out {out}: folder exists and holds files", "--force")
    assert main(["--out", str(out), "--steps", "generate,identify", "--force"]) == 0


def test_unknown_steps_are_named(tmp_path: Path, one_line_error) -> None:
    assert main(["--out", str(tmp_path / "d"), "--steps", "generate,coffee"]) == 2
    one_line_error("--steps: unknown step(s) coffee", "generate")
    assert not (tmp_path / "d").exists()


def test_sizes_follow_full() -> None:
    assert Demo(Path("x")).size(1, 2) == 1 and Demo(Path("x"), full=True).size(1, 2) == 2
    assert list(STEPS)[:2] == ["generate", "identify"] and "transfer" in STEPS
    # the winch robot and the lab export need nothing an earlier step wrote
    assert {"winch_robot", "ntrt_take"} <= set(STEPS)
