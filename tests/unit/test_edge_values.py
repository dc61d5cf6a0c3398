"""Values are checked where they enter: anchors, params files, effect parameters and
numeric options are finite and physical, else one line naming the option, exit 2."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from identification.data.dataset import read_dataset
from identification.linear.anchors import check_anchor, parse_anchor
from identification.linear.regression import SpringRodIdentifier
from tensegrity_env.assemblies import icosahedron
from tensegrity_env.effects import effect_from_dict
from tensegrity_env.io_utils import InputError, check_number
from tensegrity_sr.cli import main

GENERATE = ["generate", "--n-train", "2", "--n-val", "0", "--n-test", "1", "--steps", "20",
            "--no-progress"]  # fmt: skip


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("data") / "tiny.h5"
    assert main([*GENERATE, "-o", str(path)]) == 0
    return path


@pytest.mark.parametrize(
    ("anchor", "words"),
    [
        ("mass[rod0]=-1", ("--anchor mass[rod0]=-1.0", "a mass must be > 0 [kg]")),
        ("mass[rod0]=0", ("a mass must be > 0",)),
        ("mass[rod0]=nan", ("--anchor mass[rod0]=nan", "finite")),
        ("stiffness[spring0]=inf", ("finite",)),
        ("damping[spring3]=-0.5", ("a damping must be >= 0 [N*s/m]",)),
        ("control_gain=-2", ("a control_gain must be > 0",)),
        ("mass[rod0]=heavy", ("'heavy' is not a number",)),
    ],
)
def test_bad_anchors_are_refused_and_nothing_is_written(
    anchor: str, words: tuple[str, ...], dataset: Path, tmp_path: Path, one_line_error
) -> None:
    out = tmp_path / "params.json"
    assert main(["identify", str(dataset), "--anchor", anchor, "-o", str(out)]) == 2
    one_line_error(*words)
    assert not out.exists()


def test_anchors_through_the_api_are_checked_too(dataset: Path) -> None:
    with pytest.raises(InputError, match="a mass must be > 0"):
        SpringRodIdentifier(anchors={"mass[rod0]": -1.0}).fit(read_dataset(dataset))
    assert parse_anchor(" mass[rod0] = 1.95") == ("mass[rod0]", 1.95)
    check_anchor("damping[spring0]", 0.0)  # no damping is physical


def test_diagnose_and_efficiency_check_anchors(dataset: Path, tmp_path: Path, one_line_error) -> None:
    assert main(["diagnose", str(dataset), "--anchor", "mass[rod0]=nan",
                 "-o", str(tmp_path / "d")]) == 2  # fmt: skip
    one_line_error("--anchor", "finite")
    assert main(["efficiency", str(dataset), "--anchor", "inertia[rod0,x]=-1",
                 "-o", str(tmp_path / "e")]) == 2  # fmt: skip
    one_line_error("--anchor", "must be > 0")
    assert not (tmp_path / "d").exists() and not (tmp_path / "e").exists()


@pytest.mark.parametrize(
    ("field", "value", "words"),
    [
        ("mass", -1.0, ("masses must be positive",)),
        ("stiffness", math.nan, ("'stiffness' contains NaN or inf",)),
        ("damping", -1.0, ("damping must be >= 0",)),
    ],
)
def test_bad_init_params_are_refused(
    field: str, value: float, words: tuple[str, ...], dataset: Path, tmp_path: Path,
    one_line_error,
) -> None:  # fmt: skip
    good = tmp_path / "good.json"
    anchor = "mass[rod0]=1.9"
    assert main(["identify", str(dataset), "--anchor", anchor, "-o", str(good)]) == 0
    doc = json.loads(good.read_text())
    doc["params"][field][0] = value
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc))  # json writes NaN as a bare NaN, which Python reads
    out = tmp_path / "h.json"
    assert main(["identify", str(dataset), "--init", str(bad), "--freeze", "mass",
                 "-o", str(out)]) == 2  # fmt: skip
    one_line_error(str(bad), *words)
    assert not out.exists()


@pytest.mark.parametrize(
    ("doc", "words"),
    [
        ({"name": "linear_drag", "params": {"translational": [math.nan, 0, 0]}}, ("NaN or inf",)),
        ({"name": "ground_contact", "params": {"impedance": 1.5}}, ("must be in (0, 1)",)),
        ({"name": "ground_contact", "params": {"friction": -1}}, ("must be >= 0",)),
        ({"name": "slack_springs", "params": {"springs": [math.nan]}}, ("whole numbers",)),
        ({"name": "slack_springs", "params": {"springs": [1.5]}}, ("whole numbers",)),
        ({"name": "slack_springs", "params": {"springs": ["a"]}}, ("not numeric",)),
        ({"name": "slack_springs", "params": {"springs": [99]}}, ("spring indices",)),
    ],
)
def test_bad_effect_parameters_are_refused(doc: dict, words: tuple[str, ...]) -> None:
    with pytest.raises(InputError) as e:
        effect_from_dict(doc, icosahedron().topology)
    assert all(w in str(e.value) for w in words) and "\n" not in str(e.value)


@pytest.mark.parametrize(
    ("argv", "option"),
    [
        (["generate", "--seed", "-1"], "--seed"),
        (["plant", "linear_drag", "--strength", "nan"], "--strength"),
        (["plant", "linear_drag", "--strength", "-1"], "--strength"),
        (["plant", "none", "--noise", "inf"], "--noise"),
        (["plant", "none", "--seed", "-1"], "--seed"),
        (["diagnose", "DATA", "--horizon", "0"], "--horizon"),
        (["diagnose", "DATA", "--smoothing", "nan"], "--smoothing"),
        (["diagnose", "DATA", "--max-effects", "-1"], "--max-effects"),
        (["diagnose", "DATA", "--floor-windows", "0"], "--floor-windows"),
        (["diagnose", "DATA", "--final-floor-windows", "-1"], "--final-floor-windows"),
        (["diagnose", "DATA", "--final-iterations", "-1"], "--final-iterations"),
        (["identify", "DATA", "--floor-windows", "0"], "--floor-windows"),
        (["identify", "DATA", "--horizon", "0"], "--horizon"),
        (["identify", "DATA", "--fraction", "nan"], "--fraction"),
        (["efficiency", "DATA", "--fractions", "inf"], "--fractions"),
        (["experiment", "paper", "--seed", "-3"], "--seed"),
        (["train", "ppo", "--timesteps", "0"], "--timesteps"),
        (["transfer", "policy.zip", "--seed", "-1"], "--seed"),
    ],
    ids=lambda a: a if isinstance(a, str) else " ".join(a[:3]),
)
def test_numeric_options_out_of_their_domain(
    argv: list[str], option: str, dataset: Path, tmp_path: Path, one_line_error
) -> None:
    argv = [str(dataset) if a == "DATA" else a for a in argv]
    folder = argv[0] in ("diagnose", "efficiency", "experiment", "train", "transfer")
    out = tmp_path / ("out" if folder else "out.h5")
    assert main([*argv, "-o", str(out)]) == 2
    one_line_error(option)
    assert not out.exists()


def test_check_number_bounds() -> None:
    check_number("--x", None, 0)  # unset passes
    check_number("--x", 0.0, 0)
    with pytest.raises(InputError, match=r"^--x must be a finite number > 0, got 0.0$"):
        check_number("--x", 0.0, 0, strict=True)
    with pytest.raises(InputError, match="<= 1"):
        check_number("--x", 2.0, 0, high=1)
    with pytest.raises(InputError, match="finite"):
        check_number("--x", math.inf)
