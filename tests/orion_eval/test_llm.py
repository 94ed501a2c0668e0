"""The optional LLM user/agent against a local OpenAI-compatible server (http.server on 127.0.0.1)."""

import json
import threading
from http.server import BaseHTTPRequestHandler, HTTPServer

import numpy as np
import pytest

from pipeline.scene import Scene
from stages import STAGES
from orion_eval.report import method_name
from orion_eval.run import _resolve, evaluate
from orion_eval.episode import EpisodeOver, EpisodeRun, Task
from orion_eval.agents import AGENTS
from orion_eval.agents.llm import LLMAgent
from orion_eval.llm import ChatClient, LLMUser, dispatch, parse_action
from orion_eval.scene import SceneContext
from orion_eval.user import SimulatedUser
from pipeline.errors import ConfigError, InputDataError, StageError


class _Server:
    """Replies with canned chat completions in order; records every request body."""

    def __init__(self, replies):
        self.replies, self.requests = list(replies), []
        outer = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self):
                body = json.loads(self.rfile.read(int(self.headers["Content-Length"])))
                outer.requests.append({"path": self.path, "body": body, "auth": self.headers.get("Authorization")})
                text = outer.replies.pop(0) if outer.replies else '{"action": "talk", "args": {"content": "?"}}'
                data = json.dumps({"choices": [{"message": {"role": "assistant", "content": text}}]}).encode()
                self.send_response(200)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(data)))
                self.end_headers()
                self.wfile.write(data)

            def log_message(self, *a):
                pass

        self.httpd = HTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.httpd.server_port}/v1"
        threading.Thread(target=self.httpd.serve_forever, daemon=True).start()

    def close(self):
        self.httpd.shutdown()


def test_parse_action_protocol():
    a = parse_action('Sure!\n```json\n{"thought": "look", "action": "retrieve_map", "args": {"obj_str": "chair"}}\n```')
    assert (a.thought, a.action, a.args) == ("look", "retrieve_map", {"obj_str": "chair"})
    with pytest.raises(InputDataError, match="unknown action 'fly'"):
        parse_action('{"action": "fly", "args": {}}')
    with pytest.raises(InputDataError, match=r"missing \['obj_id'\] for goto_object"):
        parse_action('{"action": "goto_object", "args": {}}')
    with pytest.raises(InputDataError, match="no JSON object"):
        parse_action("I will go left")


def test_client_bounds_requests_and_sends_the_protocol():
    srv = _Server(["hello", "again"])
    try:
        c = ChatClient(srv.url, "m1", api_key="k", max_requests=2)
        assert c.chat([{"role": "user", "content": "hi"}]) == "hello"
        assert c.chat([{"role": "user", "content": "hi"}]) == "again"
        with pytest.raises(StageError, match=r"max_requests \(2\) reached"):
            c.chat([{"role": "user", "content": "hi"}])
        assert len(srv.requests) == 2 and srv.requests[0]["path"] == "/v1/chat/completions"
        assert srv.requests[0]["body"]["model"] == "m1" and srv.requests[0]["auth"] == "Bearer k"
    finally:
        srv.close()


def test_llm_agent_and_user_drive_an_episode(tiny_scene):
    ws, params = tiny_scene
    ctx = SceneContext(Scene(ws, params, "tiny", STAGES, check=True))

    def new_run(goal, ep):
        return EpisodeRun(ctx, Task("tiny", "llm", "yesno", 0, goal.id, ep.id, ep.start, ep.geodesic_m),
                          SimulatedUser(ctx, goal, "yesno", np.random.default_rng(0)), 2000, 5)

    def reaching_candidates(goal, ep):
        """Map candidates on the goal whose approach the user confirms (some see the goal from its back)."""
        probe = new_run(goal, ep)
        found = []
        for i, _, _ in probe.modules.retrieve_map(goal.name, "vlmap"):
            if not ctx.footprint_mask(goal.object_keys).reshape(-1)[probe.modules.objects[i].cells].any():
                continue
            run = new_run(goal, ep)
            run.modules.retrieve_map(goal.name, "vlmap")
            if run.modules.goto_object(i) and run.user.judge(run.body.pose)["success"]:
                found.append(i)
        return found

    goal, ep, ids = next((g, e, ids) for g in ctx.scene.goals.goals for e in ctx.scene.routes.for_goal(g.id)[:1]
                         if (ids := reaching_candidates(g, e)))
    replies = [
        json.dumps({"thought": "where is it", "action": "retrieve_map", "args": {"obj_str": goal.name}}),
        json.dumps({"thought": "go", "action": "goto_object", "args": {"obj_id": ids[0]}}),
        json.dumps({"thought": "ask", "action": "talk", "args": {"content": f"Is this {goal.name}?"}}),
        "Yes, you found it.",  # the LLM user's answer
    ]
    srv = _Server(replies)
    try:
        client = ChatClient(srv.url, "m", max_requests=10)
        task = Task("tiny", "llm", "yesno", 0, goal.id, ep.id, ep.start, ep.geodesic_m)
        user = SimulatedUser(ctx, goal, "yesno", np.random.default_rng(0))
        user.llm = LLMUser(client, goal)
        run = EpisodeRun(ctx, task, user, 2000, 5)
        with pytest.raises(EpisodeOver, match="success"):
            LLMAgent(ctx.params, client, max_turns=5).run(run.modules, user.instruction(), goal.name)
        assert run.success and run.talk_turns == 1
        assert run.dialogue[-1] == {"speaker": "user", "text": "Yes, you found it.", "kind": "llm", "step": run.body.steps}
        obs = srv.requests[1]["body"]["messages"][-1]["content"]
        assert obs.startswith("observation: [") and '"obj_id"' in obs  # retrieve_map's result went back
        assert len(srv.requests) == 4
        assert dispatch(run.modules, parse_action('{"action": "double_check", "args": {"obj_id": 999}}')) \
            == "unknown obj_id 999"
    finally:
        srv.close()


def _with_llm(params, **llm):
    ev = params.eval
    return params.model_copy(update={"eval": ev.model_copy(update={"llm": ev.llm.model_copy(update=llm)})})


def test_the_llm_agent_is_built_from_the_registry_like_any_agent(tiny_scene, tmp_path):
    ws, params = tiny_scene
    assert AGENTS["llm"] is LLMAgent and method_name("llm") == "LLM agent"
    with pytest.raises(ConfigError, match=r"--methods: method 'llm' cannot run: it needs eval\.llm\.base_url"):
        evaluate(ws, params, STAGES, tmp_path, methods=["llm"], progress=False)
    user_only = _with_llm(params, base_url="http://127.0.0.1:9/v1", roles="user")
    with pytest.raises(ConfigError, match=r"method 'llm' cannot run: eval\.llm\.roles is 'user'"):
        evaluate(ws, user_only, STAGES, tmp_path, methods=["llm"], progress=False)
    srv = _Server([])  # every reply: talk, so each episode ends after eval.max_talk_turns questions
    try:
        agent_only = _with_llm(params, base_url=srv.url, roles="agent", max_requests=1000)
        assert "llm" not in _resolve(agent_only, None, None, None, None)[1]  # evaluated only when named
        res = evaluate(ws, agent_only, STAGES, tmp_path / "eval", methods=["llm"], feedback=["yesno"], seeds=[0],
                       progress=False, report=False)
        episodes = res["overall"]["llm"]["yesno"]["episodes"]
        assert episodes > 0
        assert len(srv.requests) == episodes * agent_only.eval.max_talk_turns
    finally:
        srv.close()
