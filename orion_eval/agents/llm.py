"""``llm``: every action chosen by a language model through the ``eval.llm`` endpoint (think-act-ask, see
:mod:`orion_eval.llm`); evaluated only when named, as it spends the endpoint's requests."""

from __future__ import annotations

from orion_eval.agents.base import Agent, AgentResources
from orion_eval.llm import AGENT_SYSTEM, ChatClient, dispatch, parse_action
from pipeline.errors import ConfigError, InputDataError


class LLMAgent(Agent):
    """An agent whose every action is chosen by the model (think-act-ask)."""

    name, label, colour = "llm", "LLM agent", "#17becf"
    by_default = False

    def __init__(self, params, client: ChatClient, max_turns: int = 40):
        super().__init__(params)
        self.client, self.max_turns = client, max_turns

    @classmethod
    def missing(cls, params) -> str | None:
        llm = params.eval.llm
        if not llm.base_url:
            return "it needs eval.llm.base_url (an OpenAI-compatible endpoint)"
        if llm.roles not in ("agent", "both"):
            return f"eval.llm.roles is {llm.roles!r}: the LLM plays the agent with roles agent or both"
        return None

    @classmethod
    def build(cls, params, resources: AgentResources) -> "LLMAgent":
        if resources.llm is None:
            raise ConfigError(f"agent {cls.name!r}: {cls.missing(params) or 'no LLM client was lent to it'}")
        return cls(params, resources.llm)

    def run(self, m, instruction: str, goal_name: str) -> None:
        messages = [{"role": "system", "content": AGENT_SYSTEM}, {"role": "user", "content": instruction}]
        for _ in range(self.max_turns):
            reply = self.client.chat(messages)
            messages.append({"role": "assistant", "content": reply})
            try:
                obs = dispatch(m, parse_action(reply))
            except InputDataError as err:
                obs = f"error: {err}"
            messages.append({"role": "user", "content": f"observation: {obs}"})
