"""Procedural feedback: the route in words from the recording's start pose (see pipeline.routes).

With the scene's goal regions (:class:`pipeline.goals.build.GoalRegions`: navigable cells within the
success distance that see the goal's mass centre, on the reconstructed mesh; stored in goals.zarr, where
the routes stage reads them) the route is planned exactly as the routes stage plans its episodes (:func:`pipeline.nav.region.route_to_goal`:
into the region's route target, else the region; facing the nearest member's mass centre), so the
text here and in ``routes.zarr`` / the evaluator's user describe the same goal. Without regions
(no reconstruction mesh) it ends within the planner's stop radius of the footprint.

Said as a person gives directions, from the agent's CURRENT pose (:meth:`Procedural.say`): "Follow this route: turn
left, go forward 5 meters." when navchat's rule allows a route (goal in another room, at most 3 parts), else a
destination point "It is about 4 meters ahead on your left." (the goal's mass centre in one of 8 directions);
distances misjudged by the user and said in whole metres, turns only as left / right / around. Read back as
``route`` ([("turn", 90.0), ("forward", 5.0)]: degrees counter-clockwise, metres) or ``destination`` ((45.0, 4.0):
bearing degrees counter-clockwise from ahead, metres).

In a building, from another floor than the goal's, the user says the stairs and what follows them, as a person
gives directions to someone who can find the stairs (they are on the robot's map): "Go up the stairs. At the top,
follow this route: turn right, go forward 4 meters." when the walk from the stairs' far end has 1..3 parts, else
"Go up the stairs. At the top, it is about 4 meters ahead on your left." (seen from the top of the stairs, facing
along them); several flights are "Go up 2 flights of stairs.". Read back as ``stairs`` (["up"], ["up", "up"]) beside
the route or destination, which then start at the stairs' far end.
"""

from __future__ import annotations

import re
from typing import Any

import numpy as np
from pydantic import Field

from pipeline.goals.feedback.base import FeedbackContext, FeedbackKind, GoalDraft, Speaker, register
from pipeline.nav.actions import procedural_allowed
from pipeline.nav.region import GoalTargets, route_to_goal

#: the 8 directions a person points in, counter-clockwise from ahead (45 degrees apart)
POINTING = ("ahead", "ahead on your left", "to your left", "behind you on the left", "behind you",
            "behind you on the right", "to your right", "ahead on your right")
#: each direction's bearing, degrees counter-clockwise from ahead, longest phrase first ("ahead on your left" is
#: read before "ahead")
DIRECTIONS = {way: 45.0 * i if i <= 4 else 45.0 * (i - 8)
              for i, way in sorted(enumerate(POINTING), key=lambda p: -len(p[1]))}
ROUTE = re.compile(r"[Ff]ollow this route: (.+?)\.?$")
POINT = re.compile(rf"[Ii]t is about ([\d.]+) meters? ({'|'.join(re.escape(d) for d in DIRECTIONS)})\.")
STAIRS = re.compile(r"Go (up|down) (?:the stairs|(\d+) flights of stairs)\.")
TURNS = {"turn around": 180.0, "turn left": 90.0, "turn right": -90.0}


def parse_route(text: str) -> list[tuple[str, float]]:
    """``[("turn", degrees counter-clockwise) | ("forward", metres)]`` of a route in words ("turn left, go forward
    5 meters"); parts it cannot read are left out."""
    out = []
    for part in (p.strip().lower() for p in text.split(",")):
        turn = next((deg for words, deg in TURNS.items() if part.startswith(words)), None)
        if turn is not None:
            out.append(("turn", turn))
            continue
        m = re.match(r"go forward ([\d.]+) meters?", part)
        if m:
            out.append(("forward", float(m.group(1))))
    return out


@register
class Procedural(FeedbackKind):
    """``None`` when there is no navigable grid, no start pose, the goal cannot be reached, or the start
    already lies in the goal (no route parts)."""

    name = "procedural"
    field = (str | None, Field(None, description="route in words from the recording's start; null = none"))
    form = "optional_text"
    parsed = {"route": list, "destination": lambda: None, "stairs": list}

    def generate(self, goal: GoalDraft, ctx: FeedbackContext) -> str | None:
        if ctx.planner is None or ctx.start_pose is None:
            return None
        footprint = ctx.footprint_mask(goal.members)
        if ctx.goal_region is not None:
            centres = np.array([ctx.objects[k].mass_center for k in goal.members], np.float64).reshape(-1, 2)
            targets = GoalTargets.of(ctx.goal_region(goal.members), footprint, ctx.planner.grid,
                                     stop_radius_m=ctx.planner.settings.stop_radius_m)
            if ctx.building is not None:  # from the start's floor, over the stairs when the goal is on another
                route = ctx.building.route_to_goal(ctx.start_floor, ctx.start_pose, ctx.floor, targets, key=goal.id,
                                                   face_xy=centres)
            else:
                route = route_to_goal(ctx.planner, ctx.start_pose, targets, key=goal.id, face_xy=centres)
        else:
            face = np.asarray(ctx.objects[goal.members[0]].mass_center)
            route = ctx.planner.route(ctx.start_pose, footprint, key=goal.id, face_xy=face)
        # a start already in the region (or a route of turns under 45 deg) has nothing to say: None
        return None if route is None or not (route.parts or getattr(route, "climbs", None)) else route.text

    def say(self, value: str | None, user: Speaker, pose) -> str | None:
        """Directions from ``pose`` (see the module docstring); None when the goal cannot be reached from there.
        The place asked from seeds each misjudgement, then 0 and the part's index for a route's distances, 1 for a
        point's."""
        goal = user.goal
        route = user.route_from(pose)
        if route is not None and getattr(route, "climbs", None):
            return self.say_stairs(route, user, pose)
        if route is None or not route.parts:
            return None
        here = user.place_key(pose)
        if procedural_allowed(route.parts, user.room_at(pose), goal.room_id):
            return f"Follow this route: {self.said_parts(route.parts, user, (*here, 0))}."
        return f"It is about {self.pointed(goal.mass_center, pose, user, (*here, 1))}."

    @staticmethod
    def said_parts(parts, user: Speaker, where: tuple[int, ...]) -> str:
        """Route parts in words, each distance misjudged for ``(*where, its index)``."""
        return ", ".join(p.kind if p.kind != "go forward" else f"go forward {user.say_metres(p.value, (*where, i))}"
                         for i, p in enumerate(parts))

    @staticmethod
    def pointed(target_xy, pose, user: Speaker, where: tuple[int, ...]) -> str:
        """"4 meters ahead on your left": the distance and direction of ``target_xy`` from ``pose``."""
        x, y, yaw = (float(v) for v in pose[:3])
        dx, dy = np.asarray(target_xy, np.float64) - (x, y)
        bearing = float(np.degrees(np.arctan2(dy, dx) - yaw))
        sector = int(round(bearing / 45.0)) % 8
        return f"{user.say_metres(float(np.hypot(dx, dy)), where)} {POINTING[sector]}"

    def say_stairs(self, route, user: Speaker, pose) -> str:
        """Directions over the stairs (a :class:`~pipeline.nav.building.FloorRoute`; see the module docstring). The
        distances after the stairs are misjudged for the place asked from, then 2 (a route's) or 3 (a point's)."""
        climbs = route.climbs
        way = "up" if climbs[-1].up else "down"
        stairs = f"Go {way} the stairs." if len(climbs) == 1 else f"Go {way} {len(climbs)} flights of stairs."
        last = route.legs[-1][1]
        if last is None or not last.parts:
            return stairs
        here, end = user.place_key(pose), "top" if climbs[-1].up else "bottom"
        if len(last.parts) <= 3:
            return f"{stairs} At the {end}, follow this route: {self.said_parts(last.parts, user, (*here, 2))}."
        lk = climbs[-1].link
        near, far = (lk.foot_xy, lk.head_xy) if climbs[-1].up else (lk.head_xy, lk.foot_xy)
        arrived = (far[0], far[1], float(np.arctan2(far[1] - near[1], far[0] - near[0])))
        return f"{stairs} At the {end}, it is about {self.pointed(user.goal.mass_center, arrived, user, (*here, 3))}."

    def parse(self, reply: str) -> dict[str, Any]:
        found: dict[str, Any] = {}
        m = STAIRS.search(reply)
        if m:
            found["stairs"] = [m.group(1)] * int(m.group(2) or 1)
        m = ROUTE.search(reply)
        if m:
            found["route"] = parse_route(m.group(1))
        m = POINT.search(reply)
        if m:
            found["destination"] = (DIRECTIONS[m.group(2)], float(m.group(1)))
        return found
