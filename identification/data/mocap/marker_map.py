"""Marker maps: which file marker is which end cap (YAML).

.. code-block:: yaml

    markers:
      R1_top: {rod: rod0, end: 0}              # end 0 or 1 of rod ``rod0``
      R1_bot: {rod: rod0, end: 1, offset: 0.012}  # marker 12 mm beyond the end-cap
                                                   # centre, along the rod's axis

``offset`` [m] is along the rod's axis, outward from the end-cap centre (a marker on a
cap's tip). With two markers per rod the rod's roll is unseen, so an offset off the
axis cannot be undone and is refused. For an unlabelled export the map names the
track ids of the first frame. Without a map, markers named ``<rod>_<end>`` (e.g.
``rod0_0``) or ``<rod>_a``/``<rod>_b`` map themselves, also behind a subject prefix
(``ico:rod0_0``, as Vicon Nexus and Motive label a subject's markers).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import yaml

from tensegrity_env.io_utils import InputError, parse_error
from tensegrity_env.topology import Topology


@dataclass(frozen=True)
class MarkerMap:
    """Marker name -> (end cap index ``2 r + end``, axial offset [m])."""

    caps: dict[str, tuple[int, float]]
    source: str

    def check_names(self, names: list[str], where: Path) -> None:
        """Every mapped marker is in the file (else one line naming the marker)."""
        missing = sorted(set(self.caps) - set(names))
        if missing:
            raise InputError(f"{where}: marker map {self.source} names {missing[0]!r}, which is not in the file")


def read_marker_map(path: str | Path, topology: Topology) -> MarkerMap:
    """Read and check a marker-map YAML against the robot's rods."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: no such marker map")
    try:
        doc = yaml.safe_load(p.read_text())
    except yaml.YAMLError as e:
        raise InputError(f"{p}: not valid YAML ({parse_error(e)})") from None
    entries = doc.get("markers") if isinstance(doc, dict) else None
    if not isinstance(entries, dict) or not entries:
        raise InputError(f"{p}: needs a 'markers:' mapping of marker name -> {{rod, end}}")
    rods = {r.name: i for i, r in enumerate(topology.rods)}
    caps: dict[str, tuple[int, float]] = {}
    for name, entry in entries.items():
        if not isinstance(entry, dict) or "rod" not in entry or entry.get("end") not in (0, 1):
            raise InputError(f"{p}: marker {name!r} needs 'rod' and 'end' (0 or 1)")
        rod = rods.get(str(entry["rod"]))
        if rod is None:
            raise InputError(f"{p}: marker {name!r}: no rod {entry['rod']!r} in the robot (has {sorted(rods)})")
        offset = entry.get("offset", 0.0)
        if isinstance(offset, list):
            raise InputError(
                f"{p}: marker {name!r}: offset must be one number along the rod's axis "
                "(two markers per rod cannot see its roll, so an offset off the axis cannot be undone)"
            )
        if isinstance(offset, (str, bool)) or not isinstance(offset, (int, float)) \
                or not math.isfinite(offset):
            raise InputError(f"{p}: marker {name!r}: offset {offset!r} is not a finite number [m]")
        offset = float(offset)
        cap = 2 * rod + int(entry["end"])
        if cap in {c for c, _ in caps.values()}:
            raise InputError(f"{p}: two markers map to end {entry['end']} of rod {entry['rod']!r}")
        caps[str(name)] = (cap, offset)
    return MarkerMap(caps, str(p))


def default_map(names: list[str], topology: Topology) -> MarkerMap | None:
    """The map implied by names ``<rod>_<0|1|a|b|end0|end1>`` covering every end cap,
    else None; a subject prefix (Vicon's and Motive's ``<subject>:<marker>``) is
    ignored."""
    rods = {r.name: i for i, r in enumerate(topology.rods)}
    caps: dict[str, tuple[int, float]] = {}
    for n in names:
        stem, _, end = n.rpartition(":")[2].rpartition("_")
        k = {"0": 0, "1": 1, "a": 0, "b": 1, "end0": 0, "end1": 1}.get(end.lower())
        if stem in rods and k is not None:
            caps[n] = (2 * rods[stem] + k, 0.0)
    if len({c for c, _ in caps.values()}) != 2 * topology.n_rods:
        return None
    return MarkerMap(caps, "marker names")
