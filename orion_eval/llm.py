"""Optional LLM-backed user and agent through any OpenAI-compatible HTTP endpoint (off by default).

Nothing is contacted unless ``eval.llm.base_url`` is set. Requests are ``POST {base_url}/chat/completions``
with ``{"model", "messages", "temperature"}``; the reply text is ``choices[0].message.content``. The
client (httpx) counts requests and stops at ``eval.llm.max_requests`` (a :class:`StageError`); each call is
bounded in time as a whole (``eval.llm.timeout_s``, retries and slow replies included), retried on 429 and 5xx
with backoff honouring ``Retry-After``, and capped in size.

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
import time
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


#: statuses worth another try: the server is busy (429) or failed for now (5xx)
RETRY_STATUSES = frozenset({408, 429, 500, 502, 503, 504})
MAX_TRIES = 4  # per call: the first request and three retries, all within the call's deadline
BACKOFF_S = 0.5  # the wait before the n-th retry is BACKOFF_S * 2**(n-1), or the server's Retry-After if longer
MAX_REPLY_BYTES = 1 << 20  # a chat completion of a few thousand tokens is ~20 kB; nothing past 1 MiB is read


class ChatClient:
    """An OpenAI-compatible chat client on httpx, bounded: at most ``max_requests`` calls per run; each call within
    ``timeout_s`` seconds in all (connecting, waiting, a reply that trickles or streams forever, and every retry);
    at most :data:`MAX_TRIES` tries, retrying 429 and 5xx answers and lost connections after a backoff that honours
    ``Retry-After``; a reply over :data:`MAX_REPLY_BYTES` is cut and refused. Every failure names the endpoint."""

    def __init__(self, base_url: str, model: str, *, api_key: str | None = None, timeout_s: float = 30.0,
                 max_requests: int = 200, temperature: float = 0.0, max_tries: int = MAX_TRIES,
                 backoff_s: float = BACKOFF_S, max_reply_bytes: int = MAX_REPLY_BYTES):
        import httpx

        self.url = base_url.rstrip("/") + "/chat/completions"
        self.model, self.api_key, self.timeout = model, api_key, float(timeout_s)
        self.max_requests, self.temperature = int(max_requests), float(temperature)
        self.max_tries, self.backoff_s, self.max_reply_bytes = int(max_tries), float(backoff_s), int(max_reply_bytes)
        self.requests = 0
        self.http = httpx.Client(follow_redirects=False, trust_env=False)

    @classmethod
    def from_params(cls, p) -> "ChatClient":
        check_llm_params(p)
        if not p.base_url:
            raise ConfigError("eval.llm.base_url is not set: the LLM user/agent is off")
        key = os.environ.get(p.api_key_env) if p.api_key_env else None
        return cls(p.base_url, p.model, api_key=key, timeout_s=p.timeout_s, max_requests=p.max_requests,
                   temperature=p.temperature)

    def chat(self, messages: list[dict]) -> str:
        """The reply text (``choices[0].message.content``) to ``messages``."""
        if self.requests >= self.max_requests:
            raise StageError(f"eval.llm.max_requests ({self.max_requests}) reached at {self.url}")
        self.requests += 1
        body = {"model": self.model, "messages": messages, "temperature": self.temperature}
        headers = {"Authorization": f"Bearer {self.api_key}"} if self.api_key else {}
        deadline = time.monotonic() + self.timeout
        why = ""
        for attempt in range(1, self.max_tries + 1):
            status, retry_after, why, data = self._post(body, headers, deadline)
            if data is not None:
                return _content(data, self.url)
            if status is not None and status not in RETRY_STATUSES:
                raise StageError(f"{self.url}: {why} (not retried: only 429, 408 and 5xx answers are)")
            wait = max(retry_after or 0.0, self.backoff_s * 2 ** (attempt - 1))
            if attempt == self.max_tries or time.monotonic() + wait >= deadline:
                break
            time.sleep(wait)
        raise StageError(f"{self.url}: no reply after {attempt} tr{'y' if attempt == 1 else 'ies'} within the "
                         f"{self.timeout:g} s deadline of a call (eval.llm.timeout_s); last: {why}")

    def _post(self, body: dict, headers: dict, deadline: float) -> tuple[int | None, float | None, str, object]:
        """One request: ``(status, Retry-After seconds, why it failed, None)`` or ``(200, None, "", parsed reply)``.
        Reading stops at ``deadline`` whatever the server does (each read waits at most the time left)."""
        import httpx

        left = deadline - time.monotonic()
        if left <= 0:
            return None, None, "the deadline passed", None
        try:
            with self.http.stream("POST", self.url, json=body, headers=headers, timeout=httpx.Timeout(left)) as r:
                if r.status_code != 200:
                    return r.status_code, _retry_after(r.headers.get("retry-after")), f"HTTP {r.status_code}", None
                chunks, size = [], 0
                for chunk in r.iter_raw():
                    chunks.append(chunk)
                    size += len(chunk)
                    if size > self.max_reply_bytes:
                        raise InputDataError(f"the reply is over {self.max_reply_bytes:,} bytes; cut there",
                                             path=self.url, expected="a chat completion")
                    if time.monotonic() > deadline:
                        return None, None, f"the reply was still coming after {self.timeout:g} s (cut)", None
        except httpx.TimeoutException:
            return None, None, f"no answer within the {self.timeout:g} s deadline", None
        except httpx.TransportError as err:
            return None, None, f"{type(err).__name__}: {err}", None
        try:
            return 200, None, "", json.loads(b"".join(chunks).decode("utf-8"))
        except (UnicodeDecodeError, ValueError, RecursionError) as err:
            raise InputDataError(f"the reply is not JSON ({str(err)[:120]})", path=self.url,
                                 expected="an OpenAI-compatible chat/completions reply") from None

    def close(self) -> None:
        self.http.close()


def _retry_after(value: str | None) -> float | None:
    """``Retry-After`` in seconds (a number of seconds or an HTTP date), None when absent or unreadable."""
    if not value:
        return None
    try:
        return max(0.0, float(value))
    except ValueError:
        from email.utils import parsedate_to_datetime

        try:
            return max(0.0, parsedate_to_datetime(value).timestamp() - time.time())
        except (TypeError, ValueError):
            return None


def _content(data, url: str) -> str:
    try:
        content = data["choices"][0]["message"]["content"]
    except (KeyError, IndexError, TypeError):
        raise InputDataError("no choices[0].message.content in the reply", path=url,
                             field="choices[0].message.content") from None
    if not isinstance(content, str):
        raise InputDataError(f"choices[0].message.content is {type(content).__name__}", path=url,
                             field="choices[0].message.content", expected="text")
    return content


@dataclass(frozen=True)
class AgentAction:
    thought: str
    action: str
    args: dict


def parse_action(text: str) -> AgentAction:
    """The think-act-ask JSON object in a model reply (text or code fences around it are skipped); linear in the
    reply's length: one JSON decode from the first ``{``. :class:`InputDataError` names what is wrong."""
    text = text or ""
    start = text.find("{")
    if start < 0:
        raise InputDataError(f"no JSON object in {text[:120]!r}", field="reply",
                             expected='{"thought": ..., "action": ..., "args": {...}}')
    try:
        obj, _ = json.JSONDecoder().raw_decode(text, start)
    except json.JSONDecodeError as err:
        raise InputDataError(f"invalid JSON: {err.msg} at character {err.pos}", field="reply") from None
    except RecursionError:
        raise InputDataError("the JSON object nests too deeply", field="reply") from None
    if not isinstance(obj, dict):
        raise InputDataError("the reply's JSON is not an object", field="reply")
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
