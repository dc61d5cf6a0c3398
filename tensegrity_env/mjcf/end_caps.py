"""A rod's end caps in an MJCF model: which sites they are, and their contact radii."""

from __future__ import annotations

from collections.abc import Collection

import mujoco
import numpy as np

from tensegrity_env.io_utils import InputError
from tensegrity_env.rotations import np_quat_to_matrix


def mj_name(m: mujoco.MjModel, obj: mujoco.mjtObj, i: int) -> str:
    return mujoco.mj_id2name(m, obj, i) or f"#{i}"


def named_sites(m: mujoco.MjModel, names: Collection[str], src: str) -> set[int]:
    """Site ids of the ``end_caps`` names; an unknown name is refused."""
    out = set()
    for name in names:
        s = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, name)
        if s < 0:
            raise InputError(f"{src}: end-cap site '{name}' does not exist")
        out.add(int(s))
    return out


def end_cap_sites(
    m: mujoco.MjModel,
    body: int,
    sites: list[int],
    arm: int | None,
    local: dict[int, np.ndarray],
    axis: int,
    named: set[int],
    src: str,
) -> list[int]:
    """The two end-cap sites of a rod, in site order.

    The sites named in ``end_caps`` when the rod has any; else its only two sites
    besides the control arm; else the site at each end along the rod's long axis
    (``axis`` of the principal frame, positions ``local``), the one nearest the axis
    among sites equally far out (a site on an end cap's surface beside its centre).
    Sites count as equally far out within 0.1 % of the rod's site span (the rounding of
    hand-written coordinates), and as equally near the axis within 1e-9 of it.
    """
    rod = mj_name(m, mujoco.mjtObj.mjOBJ_BODY, body)
    why = "the end caps are the points motion capture tracks and the floor touches"
    mine = [s for s in sites if s in named]
    if named and mine:
        if len(mine) != 2:
            raise InputError(
                f"{src}: rod '{rod}': {len(mine)} end-cap sites named, needs 2 ({why})"
            )
        return sorted(mine)
    cands = [s for s in sites if s != arm]
    if len(cands) < 2:
        raise InputError(
            f"{src}: rod '{rod}' has {len(cands)} site(s) besides its control arm and needs two"
            f" end-cap sites ({why})"
        )
    if len(cands) == 2:
        return sorted(cands)
    along = np.array([local[s][axis] for s in cands])
    off = np.array([np.linalg.norm(np.delete(local[s], axis)) for s in cands])
    span = float(np.ptp(along))
    tol = 1e-9 * (1.0 + span)
    ends = []
    for extreme in (along.min(), along.max()):
        out = [k for k in range(len(cands)) if abs(along[k] - extreme) <= 1e-3 * span + tol]
        near = [k for k in out if off[k] <= off[out].min() + tol]
        if len(near) > 1:
            names = ", ".join(f"'{mj_name(m, mujoco.mjtObj.mjOBJ_SITE, cands[k])}'" for k in near)
            raise InputError(
                f"{src}: rod '{rod}': cannot tell which of sites {names} is the end cap ({why});"
                " name the end-cap sites (end_caps)"
            )
        ends.append(cands[near[0]])
    return sorted(ends)


def floor_geoms(m: mujoco.MjModel) -> list[int]:
    """Planes on the world body (the floor), by geom id."""
    return [
        g
        for g in range(m.ngeom)
        if m.geom_bodyid[g] == 0 and int(m.geom_type[g]) == int(mujoco.mjtGeom.mjGEOM_PLANE)
    ]


def touches(m: mujoco.MjModel, g: int, floor: list[int]) -> bool:
    """Whether geom ``g`` can collide with any floor plane (contype/conaffinity bits)."""
    return any(
        (m.geom_contype[g] & m.geom_conaffinity[f]) or (m.geom_contype[f] & m.geom_conaffinity[g])
        for f in floor
    )


#: geom types an end cap may be: a sphere centred at the end-cap site, or a capsule or
#: cylinder with one end of its axis there
CAP_TYPES = {
    int(mujoco.mjtGeom.mjGEOM_SPHERE): "sphere",
    int(mujoco.mjtGeom.mjGEOM_CAPSULE): "capsule",
    int(mujoco.mjtGeom.mjGEOM_CYLINDER): "cylinder",
}


def end_cap_radius(
    m: mujoco.MjModel, body: int, sites: list[int], floor: list[int], src: str
) -> tuple[list[float], list[int]]:
    """Contact radius of each of a rod's end caps [m]: the geom found at each end-cap site.

    A geom is at a site when it is a sphere centred there or a capsule/cylinder whose
    axis ends there; with a floor, only geoms that can collide with it count. Where
    several are, the largest radius is the one that meets the floor. 0 without a floor
    and no such geom; refused when a floor is present and an end cap has none. The two
    end caps may differ (a sphere of its own size at each end).

    Returns:
        the radii [m], in the order of ``sites``, and the end-cap geoms (ids).
    """
    radii, cap_geoms = [], []
    for s in sites:
        x = m.site_pos[s]
        found, geoms = [0.0], [-1]
        for g in range(m.ngeom):
            if m.geom_bodyid[g] != body or int(m.geom_type[g]) not in CAP_TYPES:
                continue
            if floor and not touches(m, g, floor):
                continue
            size, pos = m.geom_size[g], m.geom_pos[g]
            tol = 1e-9 * (1.0 + float(np.abs(pos).max()) + float(size[0]))
            if int(m.geom_type[g]) == int(mujoco.mjtGeom.mjGEOM_SPHERE):
                ends = [pos]
            else:
                half = np_quat_to_matrix(m.geom_quat[g]) @ np.array([0.0, 0.0, size[1]])
                ends = [pos - half, pos + half]
            if any(float(np.linalg.norm(x - e)) <= tol for e in ends):
                found.append(float(size[0]))
                geoms.append(g)
        if floor and max(found) == 0.0:
            raise InputError(
                f"{src}: rod '{mj_name(m, mujoco.mjtObj.mjOBJ_BODY, body)}': no sphere, capsule or"
                f" cylinder end that meets the floor at end-cap site"
                f" '{mj_name(m, mujoco.mjtObj.mjOBJ_SITE, s)}' (ground contact needs the end"
                " cap's radius)"
            )
        radii.append(max(found))
        cap_geoms.append(geoms[int(np.argmax(found))])
    return radii, [g for g in cap_geoms if g >= 0]
