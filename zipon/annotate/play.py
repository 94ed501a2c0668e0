"""Play as the user: an agent of the evaluator runs one episode while a person answers its questions.

The episode is the evaluator's own (:class:`orion_eval.episode.EpisodeRun`, the agent's ``run``): only the user is
replaced. Success is still judged geometrically (the simulated user's rule); when the agent asks elsewhere, the
question waits for the person's reply, with the simulated user's reply offered as a suggestion. The finished
episode is stored as the evaluator stores episodes, with ``feedback: human``, one JSON line each in
``DATA/eval/human/<scene>.episodes.jsonl``.
"""

from __future__ import annotations

import json
import secrets
import threading

import numpy as np

from orion_eval.run import human_episodes_path
from orion_eval.user import HUMAN_FEEDBACK, SimulatedUser

REPLY_TIMEOUT_S = 900.0  # an unanswered question ends the episode ("no reply")
HUMAN = HUMAN_FEEDBACK  # the feedback setting of the stored episodes
VIEW_SIZE = (120, 160)  # ego view shown to the person (height, width)


class HumanUser(SimulatedUser):
    """The simulated user's success rule; the person's replies."""

    def __init__(self, session: "PlaySession", *args):
        super().__init__(*args)
        self.session = session

    def respond(self, pose, question: str = "") -> tuple[bool, str, str]:
        ok, suggestion, _ = super().respond(pose, question)
        if ok:
            return True, suggestion, "yes"
        reply = self.session.ask(question, suggestion)
        return False, reply, HUMAN


class PlaySession:
    """One episode of ``method`` toward ``goal_id`` (the routes' start for ``seed``), run in its own thread."""

    def __init__(self, workspace, params, scene: str, method: str, goal_id: str, seed: int = 0):
        from orion_eval.agents import build_agent
        from orion_eval.episode import EpisodeRun, Task, start_pose
        from orion_eval.scene import SceneContext
        from pipeline.errors import InputDataError
        from pipeline.scene import Scene
        from stages import STAGES

        self.id = secrets.token_hex(6)
        self.workspace, self.scene = workspace, scene
        self.ctx = SceneContext(Scene(workspace, params, scene, STAGES, check=True))
        goals = {g.id: g for g in self.ctx.scene.goals.goals}
        if goal_id not in goals:
            raise InputDataError(f"no goal {goal_id!r} in scene {scene}", field="goal",
                                 expected=f"one of {sorted(goals)}")
        episodes = self.ctx.scene.routes.for_goal(goal_id)
        if not episodes:
            raise InputDataError(f"goal {goal_id!r} has no route (unreachable)", field="goal")
        goal = goals[goal_id]
        e = episodes[seed % len(episodes)]
        task = Task(scene, method, HUMAN, int(seed), goal_id, e.id, start_pose(e.start, seed, len(episodes)),
                    float(e.geodesic_m))
        self.agent = build_agent(method, params)
        rng = np.random.default_rng([int(seed), list(goals).index(goal_id)])
        user = HumanUser(self, self.ctx, goal, "mixed", rng)
        ep = params.eval
        self.run = EpisodeRun(self.ctx, task, user, ep.max_steps, ep.max_talk_turns)
        self.goal = goal
        self.question: dict | None = None
        self.result: dict | None = None
        self.error: str | None = None
        self._reply: str | None = None
        self._cond = threading.Condition()
        self._renderer = None
        self._thread = threading.Thread(target=self._play, name=f"play-{self.id}", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------------- the agent's side (its thread)

    def _play(self) -> None:
        from orion_eval.agents import run_agent
        from orion_eval.episode import EpisodeOver

        try:
            run_agent(self.agent, self.run.modules, self.run.user.instruction(), self.goal.name, (EpisodeOver,))
            reason = "gave up"
        except EpisodeOver as over:
            reason = over.reason
        except Exception as err:  # noqa: BLE001 - shown on the page; the server keeps running
            self.error = f"{type(err).__name__}: {err}"
            with self._cond:
                self._cond.notify_all()
            return
        result = self.run.result(reason)
        self._store(result)
        with self._cond:
            self.result = result
            self._cond.notify_all()

    def ask(self, question: str, suggestion: str) -> str:
        """Block the agent until the person replies (the episode ends after :data:`REPLY_TIMEOUT_S`)."""
        from orion_eval.episode import EpisodeOver

        with self._cond:
            self.question = {"text": question, "suggestion": suggestion, "step": self.run.body.steps}
            self._reply = None
            self._cond.notify_all()
            if not self._cond.wait_for(lambda: self._reply is not None, timeout=REPLY_TIMEOUT_S):
                self.question = None
                raise EpisodeOver("no reply")
            reply, self._reply = self._reply, None
            return reply

    def _store(self, result: dict) -> None:
        path = human_episodes_path(self.workspace, self.scene)
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(path, "a", encoding="utf-8") as f:
            f.write(json.dumps(result, sort_keys=True) + "\n")

    # ------------------------------------------------------------------------- the person's side (requests)

    def reply(self, text: str) -> None:
        with self._cond:
            if self.question is None:
                from pipeline.errors import InputDataError

                raise InputDataError("the agent is not waiting for a reply", field="text")
            self._reply, self.question = text, None
            self._cond.notify_all()

    def wait(self, timeout: float) -> None:
        """Until the agent asks, finishes or fails (or ``timeout`` seconds)."""
        with self._cond:
            self._cond.wait_for(lambda: self.question is not None or self.result is not None
                                or self.error is not None, timeout=timeout)

    def state(self) -> dict:
        body = self.run.body
        status = ("failed" if self.error else "done" if self.result is not None else
                  "waiting" if self.question is not None else "running")
        out = {"id": self.id, "status": status, "method": self.run.task.method, "goal": self.goal.id,
               "goal_name": self.goal.name, "instruction": self.run.user.instruction(),
               "pose": [round(float(v), 3) for v in body.pose], "poses": [list(p) for p in list(body.poses)],
               "steps": body.steps, "dialogue": list(self.run.dialogue), "question": self.question,
               "error": self.error}
        if self.result is not None:
            out["result"] = {k: self.result[k] for k in ("success", "spl", "sit", "talk_turns", "steps", "end")}
        return out

    def ego_png(self) -> bytes:
        from orion_eval.egoview import EgoRenderer
        from zipon.annotate.scene import _png

        if self._renderer is None:
            c = self.ctx
            self._renderer = EgoRenderer(c.scene.recon.mesh_path, floor_z=c.scene.recon.floor_z,
                                         camera_height_m=c.scene.camera_height_m, size=VIEW_SIZE,
                                         hfov_deg=c.params.task.hfov_deg)
        return _png(self._renderer.render(tuple(self.run.body.pose)).rgb)
