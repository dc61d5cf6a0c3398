"""What ``identify`` and ``diagnose`` say of the floor fit's two starts
(:class:`~identification.trajectory.floor_declared.StartCheck`)."""

from __future__ import annotations

from typing import Any

from identification.trajectory.floor_declared import StartCheck


def two_starts_report(starts: StartCheck | None) -> dict[str, Any]:
    """Print what the floor fit's two starts showed (a warning where they end more than
    :data:`~identification.trajectory.floor_declared.STARTS_APART` apart), and return it
    for the params file's provenance (``{"tried": False}`` where one start ran)."""
    if starts is None:
        print("the floor fit ran from one start (--effort quick): a second minimum is not "
              "looked for")  # fmt: skip
        return {"tried": False}
    if starts.apart:
        print(f"warning: {starts.line()}; the data, or the fit, does not single out one model: "
              "read the masses, inertias and stiffnesses with care (--params with a better "
              "start, or longer data)")  # fmt: skip
    else:
        print(starts.line())
    return {"tried": True, **starts.as_dict()}
