"""The Rutgers/Yale 3-bar crawl: the lab's own JSON layout to the general readers' formats.

``../shared/real/bekris_3bar/`` (evaluation data, never copied into the repository) holds
one take as the lab's pipeline left it: a JSON list of records, one per tracked frame,
with end-cap centres in units of 0.1 m and the six motor commands, and the lab's robot
description (its engine config, lengths also x10). This script writes, at run time:

* ``crawl.csv``: a plain CSV ``time, <rod>_<0|1>_<x|y|z>, ...`` of the end caps [m],
  times [s] from the first record (each record's own time, uneven as logged);
* ``crawl_commands.csv``: the command log ``time, <cable>, ...``, one column per winch
  in the robot file's order; a record's command holds from its time to the next. The
  lab's command ``+1`` winds its cable in (the rest length shrinks); a winch command
  here lengthens at ``+1`` (:mod:`tensegrity_env.engine.winch`), so each is negated;
* ``crawl_robot.xml``: the robot at physical scale (:func:`robot_mjcf`), six winch
  cables declared by the ``winch:<cable>`` numerics (docs/mjcf.md).

Then ``tensegrity-sr import-mocap crawl.csv --robot crawl_robot.xml --units m
--commands crawl_commands.csv -o crawl.h5`` reads it like any lab's export.

    python benchmarks/bekris_crawl.py ../shared/real/bekris_3bar -o /tmp/crawl
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from identification.data.mocap.commands import write_commands  # noqa: E402
from tensegrity_env.io_utils import InputError, atomic_write_text  # noqa: E402

#: the take and the lab's engine config inside the data folder
TAKE = "raw/5d_processed_data.json"
CONFIG = "robot/configs/3_bar_tensegrity_upscaled_5d.json"
#: the lab stores lengths in units of 0.1 m (its README: "stored x10")
LENGTH = 0.1
#: kg per unit of the lab's masses: motion fixes only the ratios K/m and c/m (which the
#: conversion keeps); this choice gives a rod of 0.418 kg, the scale of a motorised rod
MASS = 0.01
#: the lab's DC motor top speed [rad/s] (220 rpm in its engine's motor model): with the
#: config's winch radius and motor speed fraction it gives the winding rate v_max
MOTOR_TOP_SPEED = 220 * 2 * math.pi / 60
#: the lab's MuJoCo model's contact (solref = direct stiffness [1/s^2] and damping [1/s]
#: per unit mass, independent of the length unit)
SOLREF = "-5000 -50"
#: record keys of the end caps, rod by rod (end 0, end 1)
CAP_KEYS = ("end_pt1", "end_pt2")


@dataclass(frozen=True)
class CrawlFiles:
    """What :func:`convert` wrote: the end caps, the command log, the robot file."""

    caps: Path
    commands: Path
    robot: Path
    frames: int
    duration: float


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except OSError as e:
        raise InputError(f"{path}: cannot read ({e.strerror})") from None
    except json.JSONDecodeError as e:
        raise InputError(f"{path}: not JSON (line {e.lineno}: {e.msg})") from None


def rod_names(config: dict[str, Any]) -> list[str]:
    """The rods of the lab's config, in its order."""
    return [r["name"] for r in config["tensegrity_robot_config"]["rods"]]


def winch_springs(config: dict[str, Any]) -> list[dict[str, Any]]:
    """The config's actuated cables, in its order (the order of the records' commands)."""
    return [s for s in config["tensegrity_robot_config"]["springs"] if s.get("type") == "actuated_cable"]


def take_arrays(records: list[dict[str, Any]], rods: list[str], where: str) -> tuple[np.ndarray, ...]:
    """Times (F,) [s] from the first record, end caps (F, 2R, 3) [m] and the lab's
    commands (F, W) of the take's records; one-line errors naming the record."""
    if not isinstance(records, list) or not records:
        raise InputError(f"{where}: expected a list of records, one per frame")
    times, caps, cmds = [], [], []
    for i, rec in enumerate(records):
        try:
            times.append(float(rec["time"]))
            caps.append([[float(x) for x in rec[f"{r}_{k}"]] for r in rods for k in CAP_KEYS])
            cmds.append([float(x) for x in rec["controls"]])
        except (KeyError, TypeError, ValueError) as e:
            raise InputError(f"{where}: record {i}: missing or not numeric: {e}") from None
    t = np.array(times)
    if (np.diff(t) <= 0).any():
        k = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
        raise InputError(f"{where}: record {k}: time {t[k]!r} does not follow {t[k - 1]!r}")
    xyz = np.array(caps) * LENGTH
    if xyz.shape[1:] != (2 * len(rods), 3):
        raise InputError(f"{where}: end caps of shape {xyz.shape[1:]}, expected ({2 * len(rods)}, 3)")
    return np.round(t - t[0], 6), xyz, np.array(cmds)


def write_caps(path: Path, time: np.ndarray, caps: np.ndarray, rods: list[str]) -> Path:
    """A plain CSV ``time, <rod>_<0|1>_<x|y|z>, ...`` of end caps (F, 2R, 3) [m]."""
    names = [f"{r}_{k}" for r in rods for k in (0, 1)]
    header = ",".join(["time", *(f"{n}_{a}" for n in names for a in "xyz")])
    rows = [",".join([f"{t:.6f}", *(f"{x:.7f}" for x in c.ravel())]) for t, c in zip(time, caps, strict=True)]
    return atomic_write_text(path, "\n".join([header, *rows]) + "\n")


def robot_mjcf(config: dict[str, Any]) -> str:
    """The lab's robot at physical scale, as MJCF (the project's convention, docs/mjcf.md).

    Rods: free bodies at the config's start pose, each a tube and two sphere end caps
    (the end caps are the sites ``<rod>_end0/1`` at the sphere centres, where the lab
    attaches its cables); mass the config's rod mass (x :data:`MASS`), the spheres the
    config's sphere mass, the tube the rest. Cables: the config's nine, between end-cap
    centres, rest lengths x :data:`LENGTH`, stiffness and damping x :data:`MASS` (K/m and
    c/m kept). Winches on the actuated cables: ``v_max`` = fraction x
    :data:`MOTOR_TOP_SPEED` x winch radius, range [0, the unwound rest length], no lag
    (the lab's motor follows its command at once), starting at the rest length minus the
    config's wound-in length. A floor with the config's friction and the lab model's
    :data:`SOLREF`; rods collide with the floor only.
    """
    robot = config["tensegrity_robot_config"]
    friction = float(config.get("contact_params", {}).get("friction", 1.0))
    body = []
    for rod in robot["rods"]:
        a, b = (np.array(p, float) * LENGTH for p in rod["end_pts"])
        c = (a + b) / 2
        ra, rb = a - c, b - c
        r_cap = float(rod["sphere_radius"]) * LENGTH
        m_cap = float(rod["sphere_mass"]) * MASS
        m_tube = float(rod["mass"]) * MASS - 2 * m_cap
        if m_tube <= 0:
            raise InputError(f"{rod['name']}: rod mass {rod['mass']} below its two spheres' {2 * rod['sphere_mass']}")
        v = lambda x: " ".join(f"{float(y):.7g}" for y in x)  # noqa: E731
        name = rod["name"]
        body.append(
            f'<body name="{name}" pos="{v(c)}">\n<freejoint name="{name}"/>\n'
            f'<geom name="{name}_tube" type="cylinder" size="{float(rod["radius"]) * LENGTH:.7g}" '
            f'fromto="{v(ra)} {v(rb)}" mass="{m_tube:.7g}" contype="2" conaffinity="1"/>\n'
            f'<geom name="{name}_cap0" type="sphere" size="{r_cap:.7g}" pos="{v(ra)}" mass="{m_cap:.7g}" '
            'contype="2" conaffinity="1"/>\n'
            f'<geom name="{name}_cap1" type="sphere" size="{r_cap:.7g}" pos="{v(rb)}" mass="{m_cap:.7g}" '
            'contype="2" conaffinity="1"/>\n'
            f'<site name="{name}_end0" pos="{v(ra)}"/>\n<site name="{name}_end1" pos="{v(rb)}"/>\n</body>'
        )
    site_of = {}
    for rod in robot["rods"]:
        for k, s in enumerate(rod["sites"]):
            site_of[s] = f"{rod['name']}_end{k}"
    tendons, winches = [], []
    for s in robot["springs"]:
        a, b = (site_of[x] for x in s["end_pts"])
        rest = float(s["rest_length"]) * LENGTH
        start = rest - float(s.get("init_act_length", 0.0)) * LENGTH
        tendons.append(
            f'<spatial name="{s["name"]}" stiffness="{float(s["stiffness"]) * MASS:.7g}" '
            f'damping="{float(s["damping"]) * MASS:.7g}" springlength="{start:.7g}">'
            f'<site site="{a}"/><site site="{b}"/></spatial>'
        )
        if s.get("type") == "actuated_cable":
            v_max = float(s["motor_speed"]) * MOTOR_TOP_SPEED * float(s["winch_r"]) * LENGTH
            winches.append(f'<numeric name="winch:{s["name"]}" data="{v_max:.7g} 0 {rest:.7g}"/>')
    gravity = " ".join(f"{float(g):g}" for g in config.get("gravity", [0, 0, -9.81]))
    return "\n".join([
        "<!-- generated by benchmarks/bekris_crawl.py from the lab's engine config at physical "
        "scale: evaluation only, never committed -->",
        '<mujoco model="bekris_3bar">',
        f'<option timestep="0.001" integrator="Euler" gravity="{gravity}"/>',
        f'<default><geom friction="{friction:.7g} 0.005 0.0001" solref="{SOLREF}"/></default>',
        "<worldbody>",
        '<geom name="floor" type="plane" size="0 0 1" contype="1" conaffinity="2"/>',
        *body,
        "</worldbody>",
        "<tendon>", *tendons, "</tendon>",
        "<custom>", *winches, "</custom>",
        "</mujoco>",
    ])  # fmt: skip


def convert(folder: Path, out: Path) -> CrawlFiles:
    """Write the take's end caps, command log and robot file under ``out``."""
    config = _read_json(folder / CONFIG)
    try:
        rods = rod_names(config)
        wound = winch_springs(config)
        xml = robot_mjcf(config)
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(f"{folder / CONFIG}: not the lab's engine config layout ({e})") from None
    time, caps, lab_cmds = take_arrays(_read_json(folder / TAKE), rods, str(folder / TAKE))
    if lab_cmds.shape[1] != len(wound):
        raise InputError(f"{folder / TAKE}: {lab_cmds.shape[1]} commands per record, the config "
                         f"has {len(wound)} actuated cables")  # fmt: skip
    out.mkdir(parents=True, exist_ok=True)
    files = CrawlFiles(
        caps=write_caps(out / "crawl.csv", time, caps, rods),
        commands=write_commands(out / "crawl_commands.csv", time, -lab_cmds, [s["name"] for s in wound]),
        robot=atomic_write_text(out / "crawl_robot.xml", xml + "\n"),
        frames=len(time),
        duration=float(time[-1]),
    )
    return files


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path, help="the take's folder (../shared/real/bekris_3bar)")
    ap.add_argument("-o", "--output", type=Path, required=True, help="folder to write the three files to")
    args = ap.parse_args(argv)
    try:
        files = convert(args.folder, args.output)
    except InputError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"{files.frames} frames over {files.duration:.3f} s: {files.caps}, {files.commands}, {files.robot}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
