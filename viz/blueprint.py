"""Default viewer layout (rerun.blueprint, rerun-sdk 0.41).

Left: a 3D view of the world (the camera frame: markers, the posed robot, axes). Right, stacked:
time-series tabs for the joint signals and a text view for the reports (Markdown documents).
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence

import rerun.blueprint as rrb


def _contents(filters) -> list[str]:
    if isinstance(filters, str):
        return [filters]
    return [str(f) for f in filters]


def default_blueprint(world: str = "/", series: Mapping[str, Sequence[str] | str] | None = None,
                      text: str = "/") -> rrb.Blueprint:
    """The jointlab layout.

    Parameters
    ----------
    world : the entity that is the 3D view's origin (its frame is the world frame, by default the
        camera frame of the motion-capture system).
    series : time-series views, ``{view name: entity path filters}`` (rerun's ``+ /a/**`` /
        ``- /b`` syntax, or plain paths). Default: one view of every scalar in the recording.
    text : root of the Markdown reports shown in the text view.
    """
    world_root = "/" + world.strip("/")
    view3d = rrb.Spatial3DView(origin=world_root, contents="$origin/**", name="world (camera frame)")
    if not series:
        plots = [rrb.TimeSeriesView(origin="/", contents="/**", name="signals")]
    else:
        plots = [rrb.TimeSeriesView(origin="/", contents=_contents(filt), name=str(name))
                 for name, filt in series.items()]
    text_root = "/" + text.strip("/")
    docs = rrb.TextDocumentView(origin=text_root, contents="$origin/**", name="reports")
    right = rrb.Vertical(rrb.Tabs(*plots) if len(plots) > 1 else plots[0], docs,
                         row_shares=[3, 1])
    return rrb.Blueprint(rrb.Horizontal(view3d, right, column_shares=[3, 2]),
                         rrb.TimePanel(expanded=True), collapse_panels=False)
