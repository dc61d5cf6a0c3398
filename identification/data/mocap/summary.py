"""What one motion-capture take holds, before it is imported: frames, markers, gaps,
noise, placeholders and which axis the markers rest along."""

from __future__ import annotations

import numpy as np

from identification.data.mocap.recording import MarkerRecording
from identification.data.quality import REPEAT_TOL, longest_run, third_difference_noise

#: markers listed one per line at most (an unlabelled export may hold hundreds of tracks)
LISTED = 40


def lowest_marker_bands(points: np.ndarray) -> np.ndarray:
    """(3,) [m]: per axis, the 5th-95th percentile band over the frames of the lowest
    seen marker's coordinate, ``points`` (F, M, 3); NaN with fewer than 10 frames seeing
    a marker. A structure on a floor keeps a narrow band along the floor's normal."""
    seen = np.isfinite(points).all(-1).any(-1)
    if seen.sum() < 10:
        return np.full(3, np.nan)
    low = np.min(np.where(np.isfinite(points), points, np.inf)[seen], axis=1)  # (F', 3)
    return np.percentile(low, 95, axis=0) - np.percentile(low, 5, axis=0)


def recording_text(rec: MarkerRecording) -> str:
    """The lines ``inspect`` prints for a motion-capture file."""
    F, M = rec.points.shape[:2]
    seen = np.isfinite(rec.points).all(-1)
    kind = ("unlabelled point clouds (track ids)" if rec.unlabelled
            else "labelled markers")  # fmt: skip
    lines = [
        f"{rec.source}: {F} frames at {rec.rate:g} Hz ({rec.time[-1] - rec.time[0]:.3g} s), "
        f"{M} {kind}, {100 * (1 - seen.mean()):.2f} % of samples unseen",
    ]
    if rec.repeated_frames:
        lines.append(f"frames repeating the frame before within {REPEAT_TOL * 1e6:g} µm, read as gaps: "
                     f"{rec.repeated_frames} ({100 * rec.repeated_frames / F:.1f} %)")  # fmt: skip
    if rec.placeholders:
        lines.append(f"placeholder samples read as unseen: {rec.placeholders}")
    bands = lowest_marker_bands(rec.points)
    if np.isfinite(bands).all():
        lines.append("lowest marker over the take, 5-95 % band: "
                     + ", ".join(f"{a} {b * 1e3:.3g} mm" for a, b in zip("xyz", bands, strict=True))
                     + " (a floor keeps its normal's band narrow)")  # fmt: skip
    lines.append("marker                 seen  longest gap    noise")
    dt = 1.0 / rec.rate
    for m in range(min(M, LISTED)):
        noise = third_difference_noise(np.diff(rec.points[:, m], n=3, axis=0), least=10)
        gap = longest_run(~seen[:, m]) * dt
        text = "    n/a" if np.isnan(noise) else f"{noise * 1e3:5.3f} mm"
        lines.append(f"  {rec.names[m]:<18} {100 * seen[:, m].mean():6.2f} %  {gap * 1e3:8.1f} ms  {text}")
    if M > LISTED:
        lines.append(f"  ... and {M - LISTED} more")
    return "\n".join(lines)
