"""The kinds of user feedback (the paper's FB), one module each (generated, said, read back), registered in
FEEDBACK_KINDS: every module of this package but ``base`` is a kind, imported here in the order of their names (a new
kind is its one new module; :mod:`pipeline.engine.codedeps` counts every module here in the code of what imports it)."""

import importlib
import pkgutil

from pipeline.goals.feedback.base import FEEDBACK_KINDS, FeedbackContext, FeedbackKind, GoalDraft, feedback_kind

for _module in sorted(m.name for m in pkgutil.iter_modules(__path__)):
    if _module != "base":
        importlib.import_module(f"{__name__}.{_module}")  # registers its kind

__all__ = ["FEEDBACK_KINDS", "FeedbackContext", "FeedbackKind", "GoalDraft", "feedback_kind"]
