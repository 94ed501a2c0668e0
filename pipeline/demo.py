"""Pictures for ``zipon demo``: one picture per artifact that exists, written under DATA/artifacts/<scene>/renders/."""

from __future__ import annotations

from pathlib import Path

from pipeline.config import Params
from pipeline.paths import Workspace
from pipeline.pictures import frames_contact_sheet


def render_all(ws: Workspace, params: Params, scenes: list[str]) -> list[Path]:
    """Render what each scene has; returns the PNG paths."""
    written: list[Path] = []
    for scene in scenes:
        out = ws.renders(scene)
        frames = ws.artifact("frames", scene)
        if frames.exists():
            written.append(frames_contact_sheet(frames, out / "frames.png"))
    return written
