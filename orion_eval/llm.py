"""Optional LLM-backed user and agent through any OpenAI-compatible HTTP endpoint (off by default).

Nothing is contacted unless ``eval.llm.base_url`` is set. Requests are ``POST {base_url}/chat/completions``
with ``{"model", "messages", "temperature"}``; the reply text is ``choices[0].message.content``. The
client counts requests and stops at ``eval.llm.max_requests`` (a :class:`StageError`).

The agent side speaks the paper's think-act-ask JSON protocol: each reply is one JSON object

    {"thought": "...", "action": "<function>", "args": {...}}

with ``action`` one of the ORION functions (:data:`AGENT_FUNCTIONS`); ``talk`` carries
``{"content": ...}``. :func:`parse_action` extracts and validates it (tolerating code fences and
text around the object); :func:`dispatch` calls the function on :class:`~orion_eval.modules.Modules`
and returns the observation string that goes back to the model. The ``llm`` agent
(:class:`orion_eval.agents.llm.LLMAgent`) loops think-act-ask until the episode ends or the step budget of the
dialogue is spent; :class:`LLMUser`
answers the agent's Talk in the user's role, given the goal's FB and the success verdict.
"""

from __future__ import annotations

import json
import math
import os
import re
import urllib.error
import urllib.request
from dataclasses import dataclass

from pipeline.errors import ConfigError, InputDataError, StageError

AGENT_FUNCTIONS = {
    "move": ("dist_m",), "rotate": ("angle_deg",), "goto_point": ("x", "y"), "goto_object": ("obj_id",),
    "retrieve_map": ("obj_str",), "detect_object": ("obj_str",), "double_check": ("obj_id",),
    "search_object": ("obj_str",), "update_memory": ("obj_id", "pos_str", "neg_str"),
    "retrieve_memory": ("obj_str",), "talk": ("content",),
}
AGENT_SYSTEM = (
    "You are a robot finding a user's personal object in a house. Reply with ONE JSON object "
    '{"thought": str, "action": str, "args": object} and nothing else. Actions: '
    + ", ".join(f"{k}({', '.join(v)})" for k, v in AGENT_FUNCTIONS.items())
    + ". Distances are metres, angles degrees (left positive). Use talk to ask the user whether you found it."
)
USER_SYSTEM = (
    "You are the user of a home robot looking for your object. Answer the robot in one or two short sentences. "
    "If the robot has found the object say 'Yes'. Otherwise start with 'No.' and use the feedback given."
)


def check_llm_params(p) -> None:
    if p.base_url and not re.match(r"^https?://", p.base_url):
        raise ConfigError(f"eval.llm.base_url: {p.base_url!r} is not an http(s) URL")


class ChatClient:
    """Minimal OpenAI-compatible chat client (urllib; bounded number of requests)."""

    def __init__(self, base_url: str, model: str, *, api_key: str | None = None, timeout_s: float = 30.0,
                 max_requests: int = 200, temperature: float = 0.0):
        self.url = base_url.rstrip("/") + "/chat/completions"
        self.model, self.api_key, self.timeout = model, api_key, float(timeout_s)
        self.max_requests, self.temperature = int(max_requests), float(temperature)
        self.requests = 0

    @classmethod
    def from_params(cls, p) -> "ChatClient":
        check_llm_params(p)
        if not p.base_url:
            raise ConfigError("eval.llm.base_url is not set: the LLM user/agent is off")
        key = os.environ.get(p.api_key_env) if p.api_key_env else None
        return cls(p.base_url, p.model, api_key=key, timeout_s=p.timeout_s, max_requests=p.max_requests,
                   temperature=p.temperature)

    def chat(self, messages: list[dict]) -> str:
        if self.requests >= self.max_requests:
            raise StageError(f"eval.llm.max_requests ({self.max_requests}) reached at {self.url}")
        self.requests += 1
        body = json.dumps({"model": self.model, "messages": messages, "temperature": self.temperature}).encode()
        headers = {"Content-Type": "application/json"}
        if self.api_key:
            headers["Authorization"] = f"Bearer {self.api_key}"
        req = urllib.request.Request(self.url, data=body, headers=headers, method="POST")
        try:
            with urllib.request.urlopen(req, timeout=self.timeout) as resp:
                data = json.loads(resp.read().decode())
        except (urllib.error.URLError, TimeoutError, json.JSONDecodeError) as err:
            raise InputDataError(f"request failed: {err}", path=self.url, expected="an OpenAI-compatible "
                                 "chat/completions endpoint") from None
        try:
            return str(data["choices"][0]["message"]["content"])
        except (KeyError, IndexError, TypeError):
            raise InputDataError("no choices[0].message.content in the reply", path=self.url,
                                 field="choices[0].message.content") from None


@dataclass(frozen=True)
class AgentAction:
    thought: str
    action: str
    args: dict


def parse_action(text: str) -> AgentAction:
    """The think-act-ask JSON object in a model reply; :class:`InputDataError` names what is wrong."""
    m = re.search(r"\{.*\}", text or "", re.S)
    if not m:
        raise InputDataError(f"no JSON object in {text[:120]!r}", field="reply",
                             expected='{"thought": ..., "action": ..., "args": {...}}')
    try:
        obj = json.loads(m.group(0))
    except json.JSONDecodeError as err:
        raise InputDataError(f"invalid JSON: {err.msg}", field="reply") from None
    action = obj.get("action")
    if action not in AGENT_FUNCTIONS:
        raise InputDataError(f"unknown action {action!r}", field="action", expected=f"one of {sorted(AGENT_FUNCTIONS)}")
    args = obj.get("args") or {}
    if not isinstance(args, dict):
        raise InputDataError("args must be an object", field="args")
    missing = [a for a in AGENT_FUNCTIONS[action] if a not in args and a not in ("pos_str", "neg_str")]
    if missing:
        raise InputDataError(f"missing {missing} for {action}", field="args", expected=str(AGENT_FUNCTIONS[action]))
    return AgentAction(str(obj.get("thought", "")), action, args)


def dispatch(m, act: AgentAction) -> str:
    """Run ``act`` on the episode's modules; the observation text for the model."""
    a = act.args
    if act.action == "move":
        m.move(float(a["dist_m"]))
        return f"moved; pose {tuple(round(v, 2) for v in m.pose)}"
    if act.action == "rotate":
        m.rotate(math.radians(float(a["angle_deg"])))
        return f"rotated; pose {tuple(round(v, 2) for v in m.pose)}"
    if act.action == "goto_point":
        return "arrived" if m.goto_point((float(a["x"]), float(a["y"]))) else "unreachable"
    if act.action in ("goto_object", "double_check"):
        oid = int(a["obj_id"])
        if oid not in m.objects:
            return f"unknown obj_id {oid}"
        if act.action == "goto_object":
            return "arrived" if m.goto_object(oid) else "unreachable"
        return str(m.double_check(oid))
    if act.action in ("retrieve_map", "detect_object"):
        res = getattr(m, act.action)(str(a["obj_str"]))
        return json.dumps([{"obj_id": i, "distance_m": round(d, 2), "angle_deg": round(math.degrees(g), 1)}
                           for i, d, g in res[:10]])
    if act.action == "search_object":
        return json.dumps({"obj_id": m.search_object(str(a["obj_str"]))})
    if act.action == "update_memory":
        oid = int(a["obj_id"])
        if oid not in m.objects:
            return f"unknown obj_id {oid}"
        m.update_memory(oid, a.get("pos_str"), a.get("neg_str"))
        return "ok"
    if act.action == "retrieve_memory":
        pos, neg = m.retrieve_memory(str(a["obj_str"]))
        return json.dumps({"positive": [i for i, _, _ in pos], "negative": neg})
    return m.talk(str(a["content"]))  # talk: the user's reply is the observation


class LLMUser:
    """The user's side played by the model: it gets the goal, its FB and whether the robot succeeded."""

    def __init__(self, client: ChatClient, goal):
        self.client, self.goal = client, goal

    def respond(self, question: str, success: bool) -> str:
        fb = json.dumps(self.goal.feedback, ensure_ascii=False)
        prompt = (f"Your object: {self.goal.name}. Feedback you may use: {fb}. The robot asks: {question!r}. "
                  f"The robot {'HAS' if success else 'has NOT'} found it.")
        return self.client.chat([{"role": "system", "content": USER_SYSTEM}, {"role": "user", "content": prompt}])
