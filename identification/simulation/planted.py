"""MuJoCo data with effects the identifier is not told about (the residual loop's test bench).

:func:`planted_dataset` writes a ground-truth MJCF of the icosahedron with one
*planted* effect, rolls it out with :func:`identification.simulation.generate.generate`, and
records the effect in the dataset's ``ground_truth.effects`` list (never read by an
identifier). Effects and their strengths (:data:`PLANTS`):

============================  =================================================  ====================
plant                         in MuJoCo                                          strengths
============================  =================================================  ====================
``none``                      nothing (the control: no effect may be found)      -
``ground_contact``            a floor at z = 0 (``GenerateSpec(ground=True)``);  friction μ
                              the structure falls, bounces and tumbles
``quadratic_drag``            ``option density`` (inertia-box fluid model)       fluid density ρ
``linear_drag``               ``option viscosity`` (inertia-box fluid model)     viscosity β
``slack_springs``             tendon ``springlength = "0 l0"`` (dead band:        number of cables
                              no spring force shorter than rest)
``joint_damping``             free-joint ``damping`` on every rod (implicit        damping b = β
                              under MuJoCo's Euler: ``linear_drag`` in its
                              implicit form)
``spring_friction``           tendon ``frictionloss`` on every spring (MuJoCo's    friction force [N]
                              soft dry-friction constraint)
============================  =================================================  ====================

Drag and spring friction are planted as their effect classes declare (their ``plant``,
:class:`~tensegrity_env.effects.base.MujocoPlant`: one MJCF attribute set to the
strength); a floor, slack cables and joint damping change the model's structure and
are planted here.

``noise`` adds i.i.d. Gaussian noise [m] to every end-cap coordinate and drops the
rod states, as motion capture would (the clean states stay in the ground truth's
reach only through the returned :class:`PlantedData`, for evaluation).
"""

from __future__ import annotations

import dataclasses
import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from identification.data.dataset import Dataset, GroundTruth, Split
from identification.defaults import PLANTS
from identification.simulation.generate import GenerateSpec, InitialConditions, generate
from tensegrity_env import assemblies
from tensegrity_env.effects import EFFECTS
from tensegrity_env.effects.base import MujocoPlant
from tensegrity_env.io_utils import InputError, check_number
from tensegrity_env.mjcf import SimOptions, to_mjcf


@dataclass(frozen=True)
class PlantSpec:
    """One planted dataset.

    Attributes:
        effect: a key of :data:`PLANTS`.
        strength: a strength name of that plant, or a number (its unit in
            :data:`identification.defaults.STRENGTH_UNITS`).
        noise: end-cap position noise std [m] (0: clean rod states are kept).
        seed: seed of every random draw (initial states, which springs are cables, noise).
        n_train, n_val, n_test: trajectories per split.
        steps: transitions per trajectory.
        control_std: random control commands [command units] (0: none).
    """

    effect: str = "none"
    strength: str | float = "moderate"
    noise: float = 0.0
    seed: int = 0
    n_train: int = 8
    n_val: int = 4
    n_test: int = 4
    steps: int = 1000
    control_std: float = 0.0

    def __post_init__(self) -> None:
        if self.effect not in PLANTS:
            raise InputError(
                f"--plant: unknown effect '{self.effect}' (choose from {sorted(PLANTS)})"
            )
        if isinstance(self.strength, str) and self.strength not in PLANTS[self.effect]:
            raise InputError(
                f"--strength: '{self.effect}' has strengths {sorted(PLANTS[self.effect])} "
                "(or give a number)"
            )
        check_number("--noise", self.noise, 0.0)
        if not isinstance(self.strength, str):
            check_number("--strength", self.strength, 0.0)
        if self.seed < 0:
            raise InputError(f"--seed: must be >= 0, got {self.seed}")

    @property
    def value(self) -> float:
        """The strength as a number."""
        s = self.strength
        return float(PLANTS[self.effect][s]) if isinstance(s, str) else float(s)

    @property
    def label(self) -> str:
        return f"{self.effect}/{self.strength}/noise={self.noise * 1e3:g}mm/seed={self.seed}"


@dataclass
class PlantedData:
    """What :func:`planted_dataset` returns.

    Attributes:
        dataset: what the identifier sees (end caps only when noisy).
        ground_truth: the true model, with the planted effect in ``effects``.
        clean: the same trajectories without noise, with rod states (for evaluation).
        spec: how it was made.
    """

    dataset: Dataset
    ground_truth: GroundTruth
    clean: Dataset
    spec: PlantSpec


def planted_mjcf(spec: PlantSpec) -> tuple[str, dict[str, Any]]:
    """The ground-truth MJCF text with the planted effect, and its ground-truth record."""
    a = assemblies.icosahedron()
    ground = spec.effect == "ground_contact"
    friction = spec.value if ground else 1.0
    xml = to_mjcf(
        a.topology, a.params, SimOptions(ground=ground, friction=friction), a.pose_p, a.pose_q
    )
    root = ET.fromstring(xml)
    record: dict[str, Any] = {"name": spec.effect, "strength": spec.strength, "value": spec.value}
    if ground:
        # MuJoCo takes the larger friction of the two geoms: give the rods the same one
        for geom in root.iter("geom"):
            if geom.get("type") == "capsule":
                geom.set("friction", f"{friction!r} 0.005 0.0001")
        record["params"] = {"friction": friction, "height": 0.0}
        record["mujoco"] = {"solref": [0.02, 1.0], "solimp": [0.9, 0.95, 0.001, 0.5, 2.0]}
    elif spec.effect == "slack_springs":
        n = int(spec.value)
        S = a.topology.n_springs
        if not 0 < n <= S:
            raise InputError(f"slack_springs: strength must be 1..{S} cables, got {n}")
        cables = np.sort(np.random.default_rng([spec.seed, 99]).choice(S, n, replace=False))
        rest = a.params.numpy()["rest_length"]
        for k, sp in enumerate(root.iter("spatial")):  # every spring, in order
            if k in cables:
                sp.set("springlength", f"0 {float(rest[k])!r}")
        record["params"] = {"springs": cables.tolist()}
    elif spec.effect == "joint_damping":
        for joint in root.iter("freejoint"):
            joint.tag = "joint"
            joint.set("type", "free")
            joint.set("damping", repr(spec.value))
        record = {"name": "linear_drag", "form": "implicit", "strength": spec.strength,
                  "value": spec.value, "mujoco": {"joint_damping": spec.value}}  # fmt: skip
    elif (plant := declared_plant(spec.effect)) is not None:
        record.update(plant_attribute(root, plant, spec.value))
    ET.indent(root)
    return ET.tostring(root, encoding="unicode"), record


def declared_plant(effect: str) -> MujocoPlant | None:
    """The MuJoCo form effect ``effect``'s class declares (None: not an effect, or none)."""
    cls = EFFECTS.get(effect)
    return None if cls is None else cls.plant


def plant_attribute(root: ET.Element, plant: MujocoPlant, value: float) -> dict[str, Any]:
    """Write ``value`` to ``plant``'s MJCF attribute in ``root`` (the model, changed in
    place); the ground-truth record's ``mujoco`` (and ``params``) entries."""
    if plant.element == "option":
        option = root.find("option")
        if option is None:
            raise ValueError("the MJCF has no <option> element to plant in")
        targets = [option]
    elif plant.element == "tendon":
        targets = list(root.iter("spatial"))
    else:
        raise ValueError(f"unknown MJCF element {plant.element!r} to plant in")
    for t in targets:
        t.set(plant.attribute, repr(value))
    out: dict[str, Any] = {"mujoco": {plant.attribute: value, "model": plant.note}}
    if plant.params:
        out["params"] = {k: value for k in plant.params}
    return out


def planted_dataset(spec: PlantSpec) -> PlantedData:
    """Generate the planted dataset of ``spec`` (see the module docstring)."""
    xml, record = planted_mjcf(spec)
    ground = spec.effect == "ground_contact"
    initial = InitialConditions(lift=(0.1, 0.5)) if ground else InitialConditions()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "icosahedron.xml"
        path.write_text(xml)
        gen = GenerateSpec(
            mjcf=str(path), n_train=spec.n_train, n_val=spec.n_val, n_test=spec.n_test,
            steps=spec.steps, seed=spec.seed, ground=ground, control_std=spec.control_std,
            initial=initial, preset="planted",
            ignore=plant.ignore if (plant := declared_plant(spec.effect)) else (),
        )  # fmt: skip
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # violent-initial-state warnings: expected here
            result = generate(gen)
    clean = result.dataset
    clean.attrs.update({"assembly": "icosahedron", "planted": dataclasses.asdict(spec)})
    true_params = assemblies.icosahedron().params
    effects = [] if spec.effect == "none" else [record]
    truth = dataclasses.replace(result.ground_truth, params=true_params, effects=effects)
    dataset = (
        add_measurement_noise(clean, spec.noise, spec.seed, stream=1000)
        if spec.noise > 0
        else clean
    )
    return PlantedData(dataset=dataset, ground_truth=truth, clean=clean, spec=spec)


def add_measurement_noise(
    dataset: Dataset, std: float = 1e-3, seed: int = 0, stream: int = 0
) -> Dataset:
    """A copy with i.i.d. Gaussian noise of ``std`` [m] on every end-cap coordinate.

    Only ``nodes`` (noisy) and ``control`` are kept: rod states are dropped, as motion
    capture would not give them. Split ``k`` (in name order) draws from the seeded
    stream ``[seed, stream + k]``.
    """
    splits = {}
    for k, (name, split) in enumerate(sorted(dataset.splits.items())):
        rng = np.random.default_rng([seed, stream + k])
        noisy = split.nodes + std * rng.standard_normal(split.nodes.shape)
        splits[name] = Split(nodes=noisy, control=split.control.copy())
    attrs = {**dataset.attrs, "measurement_noise_std": float(std)}
    return Dataset(dataset.topology, dataset.dt, splits, attrs=attrs, path=None)
