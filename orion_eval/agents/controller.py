"""One think-act-ask controller over the ORION modules; every method is a set of modules it may use.

As in the paper, the baselines are the ORION framework with the same controller and fewer modules
(:class:`ModuleSet`): CoW explores and localises with CLIP saliency (no map, no memory); VLMap and CF
retrieve from their map (no detection, exploration or memory); ORION has the map, exploration, the
grounded detector and memory. The controller is scripted and deterministic (the LLM agent of
:mod:`orion_eval.llm` stays an option); it never asks which method it is, only which modules it has.

Each turn it **thinks** (ranks candidates), **acts** (walks to the best one; a method with a detector
double-checks a map candidate before asking, once the map has been wrong for several turns:
:attr:`ModularAgent.double_check_after`) and **asks** ("Is this X?"). The user's reply changes what it
searches for and where, through the same rules for every method:

- *yes/no*: the place is rejected (and, with memory, remembered as not the goal);
- *corrective* ("This is Bob's chair, not Alice's chair."): only memory can use it: the object is remembered
  as what the user called it, which helps when a later goal of the scene is that object;
- *descriptive* ("It is a red chair made of wood."): the description is a detector's prompt, never a map query
  (the map is asked for the goal's name, as the paper's reference code asks it for the target noun): it narrows
  the name, it does not replace it: every spin and exploration of a detector looks for both (what is seen as
  the description is tried first, what is seen only as the name after it); a method with a detector also
  verifies each candidate with it before asking, as the paper's controller filters detections by the
  description: standing at the candidate, an object its detector sees as the goal's name but not as the
  description (another colour or material) is passed over without a question and the search goes on
  (:meth:`~orion_eval.modules.Modules.check_attributes`). So a description helps what reads the ego view (the
  paper: detection "maintains the fine-grained visual semantics", a map "may lose these nuances"); a method
  with only a map gains nothing from it;
- *landmark* ("It is next to the bed."): the landmarks are located with the method's own modules (map
  retrieval, else a detector's spin that looks for the landmarks and the goal at once, then exploration
  for the landmarks; each landmark once per episode) and the goal is searched near them: map candidates
  ranked by distance to the landmarks, and, without a map, what the search saw of the goal next to a landmark (what
  it saw away from every landmark is held, tried after the landmark's neighbourhood: :meth:`ModularAgent.
  find_landmarks`), else a detector's spin at the landmark instance nearest the other hints (with a map too: the map says where the
  landmark is, the detector looks for the goal around it; without a map, when that spin shows nothing, a spin from each
  of the landmark's other sides in turn: :meth:`ModularAgent.look_at_focus`); a method with a map and no detector, which
  cannot look around, tries the name's candidates next to a landmark first, then walks to the landmark itself and asks
  there (the goal is next to it), then the other candidates (:meth:`ModularAgent.next_to_landmarks`; a candidate that
  is a landmark instance itself is not next to it); without a map, a landmark instance the user said "No" next to,
  naming the same landmark again, is passed over and the landmark looked for again once its neighbourhood is searched
  (:meth:`ModularAgent.pass_over_sighted`: a sighting is only the instance that was in view), and so is one
  the look around at it reads in another colour or material than the user said, as a described goal is checked
  (:meth:`ModularAgent.landmark_passed`);
- *procedural* (a route, or "It is about 4 meters to your left."): the route is walked to its end (the
  point is walked to) and the goal is searched there: map candidates nearest the end first, a
  detector's spin there first;
- *mixed*: the kinds combine rather than follow one another: the description and the name are the queries
  of every spin (the description's first), the route's end picks which instance of each landmark is meant (the
  one nearest it), a detector looks around at the route's end first, as the route alone would (without a map,
  that spin looks for the landmarks and the goal together), and around the landmark only when it saw nothing
  there, and the map's candidates of the name are ranked by distance to the route's end (in whole metres: the
  route is not precise), then by the landmarks (a map without a detector: by its landmark tiers within each metre).

An exploration searches for one target at a time, and starts over from where the agent stands when the target
changes (:meth:`ModularAgent.explore_for`, as CoW's frontier-based exploration resets its frontier map for a new
target): the goal's search after a landmark was found explores outward from the landmark, and a one-prompt
localiser's search starts over when a description replaces its prompt.

A spin is remembered where it was made (:meth:`~orion_eval.modules.Modules.look_around_for`): looking
around again there for the same thing costs no steps.

In a building the agent looks on its own floor first and takes the stairs when something points to another floor:
candidates are ranked by floor first (the floor the last hint points to, else the agent's own: a map candidate on
another floor is tried once its own floor's are rejected, and ``goto_object`` climbs to it); the user's procedural
reply names the stairs ("Go up the stairs. At the top, ..."), which the agent climbs before walking the rest; a
landmark reply from another floor says the floor ("It is upstairs."), and the agent goes there before it looks for
the landmarks (a map's landmark instances on the agent's floor count first); an exploration with no frontier left
on its floor goes on on the next floor (:meth:`~orion_eval.modules.Modules.floor_to_explore`). A rejected place is
rejected on its floor only.

Without anything left to try, a method that explores searches the frontiers with its detector, for as long
as frontiers are left and its search still moves it (``eval.explore_max_targets`` bounds one search, not the
episode: giving up with unexplored rooms left would waste the step budget); one with a detector and no exploration
looks around where it stands (the paper's "ORION w/o exp" keeps the 360° spin) and gives up when that shows nothing
new; one without a detector gives up.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.distance import cdist

from orion_eval.agents.base import Agent, ParsedFeedback, parse_feedback


@dataclass(frozen=True)
class ModuleSet:
    """Which ORION modules a method has (the paper's baselines section)."""

    map: str | None = None  # semantic map retrieved from: 'vlmap' | 'cfmap' | 'orion' (eval.orion_map) | None
    detector: str | None = None  # ego-view detection: 'grounded' (ORION's) | 'saliency' (CoW's CLIP Grad-CAM) | None
    explore: bool = False  # frontier-based exploration
    memory: bool = False  # ORION's positive / negative memory maps, carried across a scene's goals

    def describe(self) -> str:
        where = "eval.orion_map" if self.map == "orion" else self.map
        parts = [f"map {where}" if self.map else "no map",
                 f"{self.detector} detection" if self.detector else "no detection",
                 "exploration" if self.explore else "no exploration", "memory" if self.memory else "no memory"]
        return ", ".join(parts)


@dataclass
class SearchState:
    """What the controller knows mid-episode."""

    name: str  # the goal's name
    description: str | None = None  # the user's description of the goal, once given
    rejected: list = field(default_factory=list)  # centres of places the user said "No" to
    rejected_floors: list = field(default_factory=list)  # the floor of each of them
    deferred: set = field(default_factory=set)  # map candidates whose double-check failed (tried last)
    held: list = field(default_factory=list)  # goal sightings away from every landmark (ModularAgent.find_landmarks)
    focus: list = field(default_factory=list)  # per hint, the (K,2) points the goal is near (landmarks, route end)
    route_end: np.ndarray | None = None  # where the user's last route (or pointed destination) ended
    spin_at: np.ndarray | None = None  # where a detector should look around next (None: done or nowhere)
    spin_then: np.ndarray | None = None  # where it looks around next when that spin sees nothing (a landmark)
    spotted: list = field(default_factory=list)  # detections of the query from that look-around, nearest first
    landmarks: dict = field(default_factory=dict)  # landmark phrase -> (K,2) places found (or None: not found)
    landmark_ids: dict = field(default_factory=dict)  # landmark phrase -> ids of the objects at those places (map or sighted)
    marks: list = field(default_factory=list)  # ids of the map's landmark instances in force (those in the hints)
    passed: dict = field(default_factory=dict)  # landmark phrase -> ids of sighted instances that proved wrong
    map_wrong: int = 0  # map candidates the user has said "No" to (ModularAgent.double_check_after)
    hint_floor: int | None = None  # the floor the user's last hint points to (a building), None: the agent's own
    one_prompt: bool = False  # the detector holds one prompt (CoW's CLIP saliency): the description replaces the name
    target: tuple = ()  # what the exploration last searched for (ModularAgent.explore_for)
    around: list = field(default_factory=list)  # [a landmark's place, the points of its sides still to look from]
    sighted: tuple | None = None  # (place, phrase, id) of the sighted landmark instance to check on arrival

    @property
    def queries(self) -> list[str]:
        """What the detector is asked for, in order: the description (once given), then the name (the map is asked
        for the name only: :meth:`ModularAgent.map_candidates`). For a phrase-grounding detector the description
        narrows the name, it does not replace it: what is seen as the name but not read as the description is still
        a candidate, after the described ones (and the detector then checks its attributes). A saliency localiser
        (:attr:`one_prompt`) computes its relevance map for the one prompt it holds, as CoW's Grad-CAM does for its
        goal text: the name, then the description (which names the class), so same-class objects of other colours
        or materials are localised only where CLIP's reading of the attributes is unbound
        (:data:`orion_eval.detector.UNBOUND_ATTRIBUTES`)."""
        if not self.description:
            return [self.name]
        return [self.description] if self.one_prompt else [self.description, self.name]

    def reject(self, obj) -> None:
        """Remember a found object's place (its centre, on its floor) as not the goal."""
        self.rejected.append(obj.center_xy)
        self.rejected_floors.append(obj.floor)

    @property
    def goal_target(self) -> tuple:
        """What a search for the goal is a search for: the goal's name (a phrase-grounding detector's prompts narrow
        it: navchat's ORION ``search_object`` takes the goal's ``target`` and a ``prompt`` that may describe it), or,
        for a one-prompt localiser, the prompt itself (CoW's ``search_object`` takes one ``target``, the text its CLIP
        scores the views against)."""
        return tuple(self.queries) if self.one_prompt else (self.name,)

    def preferred_floor(self, agent_floor: int) -> int:
        """The floor searched first: the one the user's last hint points to, else the agent's own."""
        return agent_floor if self.hint_floor is None else self.hint_floor

    def hint_points(self) -> np.ndarray | None:
        """``(K,2)`` points of every hint in force (the landmarks found, a route's end), or None without hints: where
        an exploration looks first (:meth:`~orion_eval.modules.Modules.frontier`)."""
        return np.vstack(self.focus) if self.focus else None

    def focus_distance(self, xy) -> float:
        """Mean over the hints of the distance from ``xy`` to the hint's nearest point (0 without hints)."""
        if not self.focus:
            return 0.0
        p = np.asarray(xy, np.float64)
        return float(np.mean([np.min(np.hypot(*(pts - p).T)) for pts in self.focus]))


class ModularAgent(Agent):
    """The one controller (see the module docstring); a subclass declares its :attr:`modules`."""

    modules: ModuleSet = ModuleSet()
    #: map candidates the user must reject before a method with a detector double-checks the map's candidates in
    #: the ego view: it trusts its map until the map has been wrong "for several turns" (the paper's account of its
    #: LLM controller, Sec. V: it turns to ``double_check`` and ``search_object`` when the map provides wrong objects
    #: for several turns); until then it asks about the map's candidate, as a method without a detector does
    double_check_after = 2

    def map_name(self) -> str | None:
        which = self.modules.map
        return self.params.eval.orion_map if which == "orion" else which

    def state(self, goal_name: str) -> SearchState:
        """A fresh episode's search state; a saliency localiser holds one prompt (:attr:`SearchState.one_prompt`)."""
        return SearchState(name=goal_name, one_prompt=self.modules.detector == "saliency")

    def run(self, m, instruction: str, goal_name: str) -> None:
        if self.modules.detector:
            m.detector = self.modules.detector
        st = self.state(goal_name)
        while True:
            oid = self.next_candidate(m, st, goal_name)
            if oid is None:
                return
            st.reject(m.objects[oid])
            fb = parse_feedback(m.talk(f"Is this {goal_name}?"))
            self.update(m, st, fb, oid, goal_name)

    # ------------------------------------------------------------------ think and act
    def skip(self, m, st: SearchState, negatives: set):
        radius = self.params.eval.reject_radius_m

        def rejected(i: int) -> bool:
            floor = m.objects[i].floor
            floors = st.rejected_floors + [0] * (len(st.rejected) - len(st.rejected_floors))  # places given bare: 0
            return self.near_any(m, i, [c for c, f in zip(st.rejected, floors) if f == floor], radius)
        return lambda i: rejected(i) or i in negatives

    def ranked(self, m, st: SearchState, ids: list[int], first: set = frozenset()) -> list[int]:
        """On the preferred floor first (the one the last hint points to, else the agent's), then nearest the hints
        (the agent's distance breaks ties; without hints: nearest the agent). After a route, the distance to its end
        comes first, in whole metres (the route is not precise), then the hints (the landmarks say where within that
        metre), then ``first`` (what was seen as the description)."""
        def key(i: int):
            return (*self.route_order(m, st, i), round(st.focus_distance(m.objects[i].center_xy), 2), i not in first,
                    m.relative(i)[0], i)
        return sorted(ids, key=key)

    @staticmethod
    def route_order(m, st: SearchState, i: int) -> tuple[bool, int]:
        """What ranks object ``i`` before anything else is weighed: off the preferred floor last, then its distance to
        the route's end in whole metres (the route is not precise; 0 without a route)."""
        xy = m.objects[i].center_xy
        end = 0 if st.route_end is None else round(float(np.hypot(*(xy - st.route_end))))
        return m.objects[i].floor != st.preferred_floor(m.floor), end

    def map_candidates(self, m, st: SearchState, which: str) -> list[int]:
        """The map's candidates of the goal's name, nearest the hints first. The map is asked for the name only, never
        for the description: the paper's ``retrieve_map`` / ``retrieve_memory`` take the target's name (its
        reference code queries the map with the target noun and gives the description, a short prompt, to
        ``detect_object``, ``search_object`` and ``double_check`` alone), so a description reaches a map method only
        through a detector it may have."""
        return self.ranked(m, st, [t[0] for t in m.retrieve_map(st.name, which)])

    def next_candidate(self, m, st: SearchState, goal_name: str) -> int | None:
        """Walk to the next object worth asking about and return its id; None when nothing is left."""
        mods, which = self.modules, self.map_name()
        while True:
            negatives: set = set()
            todo: list[int] = []
            if mods.memory:
                positives, neg = m.retrieve_memory(goal_name)
                negatives = set(neg)
                todo += [t[0] for t in positives]
            if mods.detector and st.spin_at is not None and not st.spotted:
                self.look_at_focus(m, st)
            todo += st.spotted
            if which:
                todo += self.map_candidates(m, st, which)
                if not mods.detector:
                    todo = self.next_to_landmarks(m, st, todo)
            todo += st.held
            skip = self.skip(m, st, negatives)
            todo = list(dict.fromkeys(i for i in todo if not skip(i)))
            todo = [i for i in todo if i not in st.deferred] + [i for i in todo if i in st.deferred]
            if not todo:
                if mods.detector and not mods.explore:
                    # no exploration: one look around where it stands (remembered there: no steps to repeat it)
                    seen = m.look_around_for(st.queries)
                    found = dict.fromkeys(t[0] for q in st.queries for t in seen[q] if not skip(t[0]))
                    st.spotted = self.ranked(m, st, list(found))
                    if st.spotted:
                        continue
                    return None
                if not mods.detector:
                    return None
                steps = m.run.body.steps
                self.explore_for(m, st, st.goal_target)
                hit = m.search_objects(st.queries, dict.fromkeys(st.queries, skip), near=st.hint_points())
                oid = hit[1] if hit else None
                if oid is None:
                    if m.can_explore(st.hint_points()) and m.run.body.steps > steps:
                        continue  # frontiers left: search on from here
                    return None
                m.goto_object(oid)
                if st.description and m.check_attributes(oid, st.name, st.description) is False:
                    st.reject(m.objects[oid])
                    continue
                return oid
            oid = todo[0]
            if not m.goto_object(oid):
                st.reject(m.objects[oid])
                continue
            checks = mods.detector and m.objects[oid].from_map and st.map_wrong >= self.double_check_after
            if checks and oid not in st.deferred and not m.double_check(oid):
                st.deferred.add(oid)
                continue
            if mods.detector and st.description and m.check_attributes(oid, st.name, st.description) is False:
                st.reject(m.objects[oid])  # seen, and not the described colour / material
                continue
            return oid

    def next_to_landmarks(self, m, st: SearchState, ids: list[int]) -> list[int]:
        """A method with a map and no detector, told the goal is next to landmarks it located on its map: the
        name's candidates next to one of them first (footprints within ``goals.landmark_radius_m``, the user's own
        rule for "next to"), then the landmarks themselves (it walks to one and asks there: it cannot look around,
        and the goal is next to it), then the other candidates, each tier in :meth:`ranked` order. Only the
        landmark places in force count (after a route, the instance of each landmark nearest its end). After a
        route its end still comes first, as in :meth:`ranked`: the tiers order what lies within one whole metre of
        distance to it (a landmark instance the map put far from the route's end does not draw the search away)."""
        if not st.marks:
            return ids
        near = [i for i in ids if self.next_to(m, i, st.marks)]
        rest = [i for i in ids if i not in near]
        tiers = near + self.ranked(m, st, [i for i in dict.fromkeys(st.marks) if i not in near]) + rest
        if st.route_end is None:
            return tiers
        return sorted(tiers, key=lambda i: self.route_order(m, st, i))

    def next_to(self, m, i: int, marks: list[int]) -> bool:
        """Whether object ``i`` is next to one of the landmark instances ``marks``: footprints within
        ``goals.landmark_radius_m``, the user's own rule for "next to". An object that is one of them itself (the map
        answered the goal's name and the landmark's with one object) is not: the user named the landmark as another
        object than the goal."""
        radius = self.params.goals.landmark_radius_m
        return any(i != j and self.footprint_gap(m, i, j) <= radius for j in marks)

    @staticmethod
    def footprint_gap(m, i: int, j: int) -> float:
        """Metres between the nearest cells of objects ``i`` and ``j`` (their footprints; 0 when they share one)."""
        return float(cdist(m.footprint_points(i), m.footprint_points(j)).min())

    def look_at_focus(self, m, st: SearchState) -> None:
        """Walk to the hinted place and look around for the query there (once per hint); when that spin sees
        nothing, on to the next hinted place (:attr:`SearchState.spin_then`). At a landmark found by exploring, a spin
        that shows nothing of the goal is followed by one from each of the landmark's other sides (:attr:`SearchState.
        around`, :meth:`~orion_eval.modules.Modules.sides_of`), until the goal is seen: the exploration that restarts
        from the landmark (:meth:`explore_for`) covers its neighbourhood first, the floor its one spin could not see."""
        while st.spin_at is not None and not st.spotted:
            target, st.spin_at, st.spin_then = st.spin_at, st.spin_then, None
            here = np.asarray(m.pose[:2])
            elsewhere = st.hint_floor is not None and st.hint_floor != m.floor
            if elsewhere or float(np.hypot(*(target - here))) > self.params.eval.reject_radius_m:
                m.goto_point(target, floor=st.hint_floor)
            check = self.landmark_check(m, st, target)
            self.look_here(m, st, check[:2] if check else ())
            skip = self.skip(m, st, set())
            if check and all(skip(i) for i in st.spotted) and self.landmark_passed(m, st, target, *check):
                continue
            sides = st.around[1] if st.around and np.allclose(st.around[0], target) else []
            while sides and all(skip(i) for i in st.spotted):
                m.goto_point(sides.pop(0))
                self.look_here(m, st)

    def look_here(self, m, st: SearchState, also: tuple = ()) -> None:
        """Look around where the agent stands: what it sees of the query becomes :attr:`SearchState.spotted`, the
        described detections first among equals, then what is seen as the name only. The same spin looks for
        ``also`` (a landmark's phrase and object: :meth:`landmark_check`)."""
        seen = m.look_around_for([*st.queries, *also])
        found = [t[0] for q in st.queries for t in seen[q]]
        described = {t[0] for t in seen[st.queries[0]]} if st.description else set()
        st.spotted = self.ranked(m, st, list(dict.fromkeys(found)), described)

    # ------------------------------------------------------------------ the user's reply
    def update(self, m, st: SearchState, fb: ParsedFeedback, oid: int, goal_name: str) -> None:
        """Change the search after a "No" (the same rules for every method; see the module docstring)."""
        if self.modules.memory:
            m.update_memory(oid, fb.corrected_as, goal_name)
        if m.objects[oid].from_map:
            st.map_wrong += 1
        st.spotted = [i for i in st.spotted if i != oid]
        if fb.description:
            st.description = fb.description
            st.spotted = []
        if fb.stairs or fb.floor_offset:  # the goal is on another floor: go there first
            m.take_stairs(m.floor + (sum(1 if w == "up" else -1 for w in fb.stairs) or fb.floor_offset))
            st.hint_floor = m.floor
            st.spotted, st.focus, st.route_end, st.marks = [], [], None, []
            st.spin_at, st.spin_then = (np.asarray(m.pose[:2], np.float64) if self.modules.detector else None), None
        if fb.route or fb.destination:
            if fb.route:
                self.follow_route(m, fb.route)
            else:
                bearing, dist = fb.destination
                x, y, yaw = m.pose
                m.goto_point((x + dist * math.cos(yaw + math.radians(bearing)),
                              y + dist * math.sin(yaw + math.radians(bearing))))
            end = np.asarray(m.pose[:2], np.float64)
            st.focus, st.route_end, st.marks = [end[None]], end, []
            st.spin_at, st.spin_then = (end if self.modules.detector else None), None
            st.spotted = []
        if fb.landmarks:  # located from where the route ended, if one came with them
            routed = bool(fb.route or fb.destination)
            if not self.map_name():
                self.pass_over_sighted(m, st, fb.landmarks, oid)
            if not routed:
                st.spotted = []
            hints = self.locate_landmarks(m, st, fb.landmarks)
            if hints:
                ids = [st.landmark_ids.get(p, []) for p in fb.landmarks if st.landmarks.get(p) is not None]
                if routed:
                    # the hints pin each other down: of each landmark, the instance that agrees with the route's end
                    keep = [self.nearest_index(pts, st.focus) for pts in hints]
                    hints = [pts[[k]] for pts, k in zip(hints, keep)]
                    ids = [found[k:k + 1] for found, k in zip(ids, keep)]
                st.focus = (st.focus if routed else []) + hints
                st.marks = [i for found in ids for i in found]
                st.spotted = self.ranked(m, st, st.spotted)
                first = next(p for p in fb.landmarks if st.landmarks.get(p) is not None)
                self.aim_at_landmark(m, st, first, hints[0], ids[0], routed)

    def aim_at_landmark(self, m, st: SearchState, phrase: str, places: np.ndarray, ids: list[int],
                        routed: bool) -> None:
        """A detector looks around at the instance of the landmark ``phrase`` (``places`` ``(K,2)`` of the objects
        ``ids``) nearest the other hints (unless the goal was seen); after a route, first at its end (as the route
        alone would), then at the landmark. Without a map the landmark was sighted: the instance is checked when the
        agent looks around there (:meth:`landmark_passed`) and, with exploration, looked at from its other sides too."""
        if not self.modules.detector:
            return
        here = np.asarray(m.pose[:2])
        k = min(range(len(places)), key=lambda j: (st.focus_distance(places[j]), float(np.hypot(*(places[j] - here)))))
        at = np.asarray(places[k], np.float64)
        if routed and st.spin_at is not None:
            st.spin_then = at
        else:
            st.spin_at = at
        if not self.map_name():
            st.sighted = (at, phrase, ids[k])
            if self.modules.explore and not (st.around and np.allclose(st.around[0], at)):
                st.around = [at, m.sides_of(at, here)]  # a landmark found by exploring: its sides too (those left)

    def landmark_check(self, m, st: SearchState, at: np.ndarray) -> tuple | None:
        """``(phrase, object, id)`` when the look around at ``at`` is at the sighted landmark instance of
        :attr:`SearchState.sighted` and the user's phrase says its colour or material ("the beige sink made of
        metal": the object "sink"), so that spin also reads it; None otherwise."""
        if st.sighted is None or not np.allclose(st.sighted[0], at):
            return None
        _, phrase, lid = st.sighted
        st.sighted = None
        name = m.ctx.object_phrase(phrase)
        return (phrase, name, lid) if name else None

    def landmark_passed(self, m, st: SearchState, at: np.ndarray, phrase: str, name: str, lid: int) -> bool:
        """The look around at the sighted landmark instance ``lid`` showed nothing of the goal: check it is the one
        the user named, as a described goal is checked (:meth:`~orion_eval.modules.Modules.read_around`): an instance
        that spin saw as the landmark's object but not with the colour or material the user said (and this sink is
        white) is passed over and the landmark looked for again, where a sighting is only the instance that happened to
        be in view. True when it was passed over (the look around aims at the instance found next, if any)."""
        if m.read_around(lid, name, phrase) is not False:
            return False
        self.pass_over(m, st, phrase, {lid})
        # its place is no longer a hint; the other instances sighted, if any, still are
        kept = [pts[~np.all(np.isclose(pts, at), axis=1)] for pts in st.focus]
        st.focus = [pts for pts in kept if len(pts)]
        st.marks = [i for i in st.marks if i != lid]
        st.around = []
        if st.landmarks.get(phrase) is None:
            self.find_landmarks(m, st, [phrase], [phrase])
            if st.landmarks.get(phrase) is not None:
                st.focus.append(st.landmarks[phrase])
        if st.landmarks.get(phrase) is not None:
            self.aim_at_landmark(m, st, phrase, st.landmarks[phrase], st.landmark_ids[phrase], routed=False)
        return True

    def pass_over_sighted(self, m, st: SearchState, phrases: list[str], oid: int) -> None:
        """Without a map a landmark is located by a sighting, and a sighting is the instance that happened to be
        in view (of two shelves, the one the spin saw). When the user says "No" to an object next to it and names
        the same landmark again, either another object next to this instance is the goal or the goal is next to
        another instance: the instance is passed over and the landmark looked for again (a map, which returns every
        instance, ranks them by the other hints instead) only once its neighbourhood is searched
        (:meth:`searched_around`)."""
        radius = self.params.goals.landmark_radius_m
        for phrase in phrases:
            ids = st.landmark_ids.get(phrase) or []
            wrong = {j for j in ids if self.footprint_gap(m, oid, j) <= radius and self.searched_around(m, st, j, oid)}
            if wrong:
                self.pass_over(m, st, phrase, wrong)

    def searched_around(self, m, st: SearchState, j: int, oid: int) -> bool:
        """Whether the neighbourhood of the sighted landmark instance ``j`` is searched, the object ``oid`` just
        rejected: nothing seen of the goal next to it is left to ask about, and no side of it is left to look from
        (:attr:`SearchState.around`). Until then a "No" next to it says only that ``oid`` is not the goal."""
        radius = self.params.goals.landmark_radius_m
        skip = self.skip(m, st, {oid})
        if any(not skip(i) and self.footprint_gap(m, i, j) <= radius for i in st.spotted):
            return False
        sides = st.around[1] if st.around and np.allclose(st.around[0], m.objects[j].center_xy) else []
        return not sides

    def pass_over(self, m, st: SearchState, phrase: str, wrong: set) -> None:
        """The sighted instances ``wrong`` of the landmark ``phrase`` are not the one meant: remembered as passed over
        and no longer its places (when none is left, it is looked for again)."""
        st.passed.setdefault(phrase, set()).update(wrong)
        left = [j for j in st.landmark_ids.get(phrase) or [] if j not in wrong]
        st.landmark_ids[phrase] = left
        if left:
            st.landmarks[phrase] = self.places(m, left)
        else:
            st.landmarks.pop(phrase, None)  # looked for again

    @staticmethod
    def places(m, ids: list[int]) -> np.ndarray | None:
        """``(K,2)`` centres of the objects ``ids`` (None when there are none: the landmark was not found)."""
        return np.asarray([m.objects[i].center_xy for i in ids], np.float64) if ids else None

    @staticmethod
    def nearest_index(pts: np.ndarray, focus: list) -> int:
        """Row of the ``(K,2)`` points ``pts`` nearest the hints ``focus`` (mean over the hints)."""
        return int(np.argmin([np.mean([np.min(np.hypot(*(f - p).T)) for f in focus]) for p in pts]))

    def locate_landmarks(self, m, st: SearchState, phrases: list[str]) -> list[np.ndarray]:
        """Find the landmarks with the method's modules: the map's candidates of each phrase, else the detector (one
        spin here for all of them, then exploration for the first phrase when none was seen and the method
        explores). Landmarks already looked for in this episode are not looked for again. One ``(K,2)`` array of
        places per landmark found."""
        which = self.map_name()
        if which:
            for phrase in (p for p in phrases if p not in st.landmarks):
                hits = [t[0] for t in m.retrieve_map(phrase, which)]
                # a building: the instances on the preferred floor, else those of the floor the nearest one is on
                floor = st.preferred_floor(m.floor)
                mine = [i for i in hits if m.objects[i].floor == floor]
                if hits and not mine:
                    st.hint_floor = m.objects[hits[0]].floor
                    mine = [i for i in hits if m.objects[i].floor == st.hint_floor]
                hits = mine
                st.landmark_ids[phrase] = hits
                st.landmarks[phrase] = self.places(m, hits)
        elif self.modules.detector:
            # a landmark not found yet is looked for again whenever the user names it: the spin where the agent
            # stands (remembered there: free when it already looked there) and the exploration, which goes on from
            # the frontiers it left
            lost = [p for p in phrases if st.landmarks.get(p) is None]
            if lost:
                self.find_landmarks(m, st, lost, phrases)
        return [st.landmarks[p] for p in phrases if st.landmarks.get(p) is not None]

    def find_landmarks(self, m, st: SearchState, lost: list[str], phrases: list[str]) -> None:
        """Without a map: one spin for the landmarks ``lost`` and the goal together (the goal itself may be in sight);
        when none of ``phrases`` is found, a method that explores searches the frontiers for every landmark not found
        (the landmarks are salient objects, easier to find than the goal: the paper's reason landmarks help
        exploration-based methods). What it sees of the goal's query on the way is kept: a sighting next to a landmark
        instance found (:meth:`next_to`) is tried first, one away from every landmark is held (:attr:`SearchState.held`: asked about once the landmark's
        neighbourhood shows nothing, as the user said the goal is next to the landmark); when no landmark is found,
        every sighting is tried. A landmark found was what the exploration last searched for (:meth:`explore_for`):
        the goal's search after it starts over from it."""
        seen = m.look_around_for([*lost, *st.queries])
        if st.spin_at is not None and float(np.hypot(*(st.spin_at - m.pose[:2]))) <= self.params.eval.reject_radius_m:
            st.spin_at = None  # the look-around due here (a route's end) is this one
        for phrase in lost:
            ids = [t[0] for t in seen[phrase] if t[0] not in st.passed.get(phrase, ())]
            st.landmark_ids[phrase] = ids
            st.landmarks[phrase] = self.places(m, ids)
        self.spot(m, st, [t for q in st.queries for t in seen[q]])
        if not any(st.landmarks.get(p) is not None for p in phrases) and self.modules.explore:
            skip = self.skip(m, st, set())
            sighted = list(st.spotted)
            while True:  # every goal sighting is a new object: ends when a landmark is found or the frontiers run out
                hit = m.search_objects([*lost, *st.queries],
                                       {**dict.fromkeys(st.queries, lambda i: skip(i) or i in sighted),
                                        **{p: st.passed.get(p, set()).__contains__ for p in lost}})
                if hit and hit[0] in st.queries:
                    sighted.append(hit[1])
                    continue
                if hit:
                    st.landmark_ids[hit[0]] = [hit[1]]
                    st.landmarks[hit[0]] = self.places(m, [hit[1]])
                break
            st.spotted = sighted
        marks = [j for p in phrases for j in st.landmark_ids.get(p) or []]
        if marks:
            near = [i for i in st.spotted if self.next_to(m, i, marks)]
            st.held = list(dict.fromkeys(st.held + [i for i in st.spotted if i not in near]))
            st.spotted = near
        found = tuple(p for p in lost if st.landmarks.get(p) is not None)
        if found and self.modules.explore:
            st.target = found

    @staticmethod
    def explore_for(m, st: SearchState, target: tuple) -> None:
        """Make ``target`` what the exploration searches for; when it is not what the last search was for, the
        exploration starts over from where the agent stands (:meth:`~orion_eval.modules.Modules.restart_exploration`:
        CoW's frontier-based exploration resets its frontier map whenever its search target changes). So once a
        landmark is found, the goal is searched outward from the landmark, its neighbourhood seen again from new
        places, rather than only at the frontiers the landmark's search left (which, the landmark's surroundings
        being marked explored by one spin there, lie away from it, and run out)."""
        if target != st.target:
            if st.target:
                m.restart_exploration()
            st.target = target

    def spot(self, m, st: SearchState, found: list) -> None:
        """Add detections of the goal's query (``(obj_id, d, a)``) to the places to try, unless rejected."""
        skip = self.skip(m, st, set())
        st.spotted = list(dict.fromkeys(st.spotted + [t[0] for t in found if not skip(t[0])]))
