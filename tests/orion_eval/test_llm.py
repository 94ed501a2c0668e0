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


def _completion(text: str) -> bytes:
    return json.dumps({"choices": [{"message": {"role": "assistant", "content": text}}]}).encode()


def _send(handler, status: int, data: bytes, **headers) -> None:
    handler.send_response(status)
    for name, value in {"Content-Type": "application/json", **headers}.items():
        handler.send_header(name.replace("_", "-"), value)
    handler.send_header("Content-Length", str(len(data)))
    handler.end_headers()
    handler.wfile.write(data)


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
                _send(self, 200, _completion(text))

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


# ----------------------------------------------------------------------------- a hostile endpoint

class _Scripted:
    """An OpenAI-compatible endpoint that answers each request by the next step of a script:
    ``("status", code, retry_after)``, ``("ok", text)``, ``("stall",)`` (headers, then nothing),
    ``("forever",)`` (a body that never ends, a byte every 20 ms), ``("raw", bytes)`` (a 200 with that body)."""

    def __init__(self, script):
        import time
        from http.server import ThreadingHTTPServer

        self.script, self.times = list(script), []
        outer = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def do_POST(self):
                self.rfile.read(int(self.headers["Content-Length"]))
                outer.times.append(time.monotonic())
                step = outer.script.pop(0) if outer.script else ("ok", "late")
                if step[0] == "status":
                    _send(self, step[1], b"{}", **({"Retry_After": str(step[2])} if step[2] is not None else {}))
                    return
                if step[0] in ("stall", "forever"):
                    self.send_response(200)
                    self.send_header("Content-Type", "application/json")
                    self.end_headers()
                    self.wfile.flush()
                    deadline = time.monotonic() + 10
                    try:
                        while time.monotonic() < deadline:
                            if step[0] == "forever":
                                self.wfile.write(b" ")
                                self.wfile.flush()
                            time.sleep(0.02)
                    except OSError:  # the client hung up: what it should do
                        pass
                    self.close_connection = True
                    return
                _send(self, 200, step[1] if step[0] == "raw" else _completion(step[1]))

            def log_message(self, *a):
                pass

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.httpd.daemon_threads = True
        self.url = f"http://127.0.0.1:{self.httpd.server_port}/v1"
        threading.Thread(target=self.httpd.serve_forever, daemon=True).start()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.httpd.shutdown()


HI = [{"role": "user", "content": "hi"}]


def test_429_is_retried_after_its_retry_after():
    with _Scripted([("status", 429, 1), ("ok", "hello")]) as srv:
        client = ChatClient(srv.url, "m", timeout_s=10, backoff_s=0.05)
        assert client.chat(HI) == "hello"
        assert len(srv.times) == 2 and srv.times[1] - srv.times[0] >= 0.95  # waited the server's Retry-After


def test_503_three_times_then_a_reply_and_four_times_is_an_error_naming_the_endpoint():
    with _Scripted([("status", 503, None)] * 3 + [("ok", "fine")]) as srv:
        assert ChatClient(srv.url, "m", timeout_s=10, backoff_s=0.2).chat(HI) == "fine"
        gaps = [b - a for a, b in zip(srv.times, srv.times[1:])]
        assert gaps[0] >= 0.2 and gaps[1] >= 0.4 and gaps[2] >= 0.8, gaps  # the backoff doubles
    with _Scripted([("status", 503, None)] * 4) as srv:
        with pytest.raises(StageError, match=rf"{srv.url}/chat/completions: no reply after 4 tries .* last: HTTP 503"):
            ChatClient(srv.url, "m", timeout_s=10, backoff_s=0.01).chat(HI)


def test_a_client_error_is_not_retried():
    with _Scripted([("status", 401, None), ("ok", "never")]) as srv:
        with pytest.raises(StageError, match=r"HTTP 401 \(not retried"):
            ChatClient(srv.url, "m", timeout_s=10, backoff_s=0.01).chat(HI)
        assert len(srv.times) == 1


@pytest.mark.parametrize("step, words", [(("stall",), "deadline"), (("forever",), "deadline")])
def test_a_stalled_or_endless_reply_is_cut_at_the_deadline_of_the_call(step, words):
    import time

    with _Scripted([step] * 5) as srv:
        client = ChatClient(srv.url, "m", timeout_s=1.0, backoff_s=0.05)
        t0 = time.monotonic()
        with pytest.raises(StageError, match=rf"{srv.url}/chat/completions: .*{words}"):
            client.chat(HI)
        assert time.monotonic() - t0 < 3.0  # the whole call, every try included, within its deadline (+ slack)


def test_a_reply_over_the_size_cap_is_refused():
    with _Scripted([("raw", b'{"choices": "' + b"x" * 5000 + b'"}')]) as srv:
        with pytest.raises(InputDataError, match=r"over 1,000 bytes"):
            ChatClient(srv.url, "m", timeout_s=10, max_reply_bytes=1000).chat(HI)


@pytest.mark.parametrize("body, words", [(b"{not json", "the reply is not JSON"),
                                         (b'{"choices": []}', r"no choices\[0\].message.content"),
                                         (b'{"choices": [{"message": {"content": 3}}]}', "is int"),
                                         (b"[" * 100_000, "the reply is not JSON")])
def test_malformed_replies_name_the_endpoint(body, words):
    with _Scripted([("raw", body)]) as srv:
        with pytest.raises(InputDataError, match=words) as err:
            ChatClient(srv.url, "m", timeout_s=10).chat(HI)
        assert f"{srv.url}/chat/completions" in str(err.value)


def test_parsing_a_reply_is_linear():
    import time

    for n in (20_000, 200_000):
        t0 = time.perf_counter()
        with pytest.raises(InputDataError):
            parse_action("{" * n)
        with pytest.raises(InputDataError):
            parse_action('{"a": ' * n)
        assert time.perf_counter() - t0 < 0.5, n  # the regex it replaced took ~11 s on 200,000 braces
    assert parse_action('note {"action": "talk", "args": {"content": "is it {this}?"}} done').args == {
        "content": "is it {this}?"}
