"""One motion-capture take in memory, and the reader that picks a file's format."""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from identification.data.quality import placeholder_samples, repeated_frames
from tensegrity_env.io_utils import InputError
from tensegrity_env.rotations import TO_Z_UP

#: metres per unit of the length units a file may state
UNIT_SCALE = {"m": 1.0, "meters": 1.0, "metres": 1.0, "mm": 1e-3, "millimeters": 1e-3,
              "millimetres": 1e-3, "cm": 1e-2, "centimeters": 1e-2, "centimetres": 1e-2}  # fmt: skip
#: marker names that mean "not labelled": Motive's ``Unlabeled 1234``, Vicon's ``*12`` and
#: the OptiTrack row format's ``Marker-1234``
UNLABELLED = re.compile(r"^(unlabeled|unlabelled)\b|^\*\d+$|^marker-\d+$", re.IGNORECASE)


@dataclass
class MarkerRecording:
    """Marker trajectories of one take.

    Attributes:
        source: the file it was read from (for messages).
        time: (F,) frame times [s], increasing; non-uniform allowed.
        points: (F, M, 3) marker positions [m], NaN where the marker was not seen.
        names: M marker names (for an unlabelled export, the exporter's track ids,
            which change when a marker is lost and found again).
        rate: the file's nominal frame rate [Hz].
        placeholders: samples the file held as positions for an unseen marker (exactly
            the origin, a held position), read as NaN (:meth:`without_placeholders`).
        repeated_frames: frames that repeated the frame before far below the noise
            (:func:`~identification.data.quality.repeated_frames`), read as gaps.
        ids: (F, M) the capture system's marker id of each sample, -1 where none, for
            exports whose columns hold several ids in turn (the OptiTrack row format);
            None when a column is one track.
    """

    source: Path
    time: np.ndarray
    points: np.ndarray
    names: list[str]
    rate: float
    placeholders: int = 0
    repeated_frames: int = 0
    ids: np.ndarray | None = None

    @property
    def n_frames(self) -> int:
        return int(self.points.shape[0])

    @property
    def unlabelled(self) -> bool:
        """Whether every track is an unlabelled id (the frames are point clouds)."""
        return bool(self.names) and all(UNLABELLED.search(n) for n in self.names)

    def check(self) -> MarkerRecording:
        """One-line :class:`InputError` naming the file on malformed content; returns self."""
        where = self.source
        if self.points.ndim != 3 or self.points.shape[2] != 3 or self.points.shape[1] == 0:
            raise InputError(f"{where}: no marker positions found")
        if self.points.shape[0] < 2:
            raise InputError(f"{where}: needs at least 2 frames, has {self.points.shape[0]}")
        if len(self.names) != self.points.shape[1]:
            raise InputError(f"{where}: {len(self.names)} marker names for {self.points.shape[1]} markers")
        if len(set(self.names)) != len(self.names) and not self.unlabelled:
            raise InputError(f"{where}: marker names repeat")
        if self.time.shape != (self.points.shape[0],) or not np.isfinite(self.time).all():
            raise InputError(f"{where}: frame times missing or not finite")
        if (np.diff(self.time) <= 0).any():
            raise InputError(f"{where}: frame times do not increase")
        if not np.isfinite(self.rate) or self.rate <= 0:
            raise InputError(f"{where}: frame rate {self.rate} is not positive")
        inf = np.isinf(self.points).any(-1)
        if inf.any():
            f, m = np.argwhere(inf)[0]
            raise InputError(f"{where}: marker positions contain inf (frame {f + 1}, marker "
                             f"{self.names[m]!r}; {int(inf.sum())} samples)")  # fmt: skip
        unseen = np.isnan(self.points)
        partly = unseen.any(-1) & ~unseen.all(-1)
        if partly.any():
            f, m = np.argwhere(partly)[0]
            raise InputError(f"{where}: frame {f + 1}, marker {self.names[m]!r}: some coordinates "
                             f"NaN and others not ({int(partly.sum())} samples; an unseen "
                             "marker is NaN in x, y and z)")  # fmt: skip
        return self

    def from_frame(self, k: int) -> MarkerRecording:
        """This take from frame ``k`` on (times still from the file's first frame)."""
        if k == 0:
            return self
        ids = None if self.ids is None else self.ids[k:]
        return replace(self, time=self.time[k:], points=self.points[k:], ids=ids)

    def z_up(self, up: str) -> MarkerRecording:
        """This take in a z-up frame, its file's vertical axis being ``up`` (x, y or z)."""
        if up == "z":
            return self
        return replace(self, points=self.points @ TO_Z_UP[up].T)

    def without_placeholders(self) -> MarkerRecording:
        """This take with its placeholder samples
        (:func:`~identification.data.quality.placeholder_samples`) and its repeated
        frames (:func:`~identification.data.quality.repeated_frames`) read as unseen
        (NaN)."""
        repeated = repeated_frames(self.points)
        mask = placeholder_samples(self.points) & ~repeated[:, None]
        if not mask.any() and not repeated.any():
            return self
        points = self.points.copy()
        points[mask] = np.nan
        points[repeated] = np.nan
        return replace(self, points=points, placeholders=self.placeholders + int(mask.sum()),
                       repeated_frames=self.repeated_frames + int(repeated.sum()))  # fmt: skip


def unit_scale(name: str | None, where: Path, option: str | None) -> float:
    """Metres per unit: the file's own unit if it states one, else ``option`` (--units)."""
    for given in (name, option):
        if given:
            key = given.strip().lower()
            if key not in UNIT_SCALE:
                raise InputError(f"{where}: unknown length unit {given!r} (use m or mm)")
            return UNIT_SCALE[key]
    raise InputError(f"{where}: the file does not state its length unit; pass --units mm or m")
