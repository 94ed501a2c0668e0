"""The four kinds of user feedback (the paper's FB), one module each, registered in FEEDBACK_KINDS."""

from pipeline.goals.feedback.base import FEEDBACK_KINDS, FeedbackContext, FeedbackKind, GoalDraft
from pipeline.goals.feedback import corrective, descriptive, landmark, procedural  # noqa: F401  (register)

__all__ = ["FEEDBACK_KINDS", "FeedbackContext", "FeedbackKind", "GoalDraft"]
