"""Personalized goals g = (type, name, room, FB) and the annotation workflow.

Modules: :mod:`~pipeline.goals.objects` (object records from GT, a user file), :mod:`~pipeline.goals.navchat`
(navchat's objects.json / final.json), :mod:`~pipeline.goals.naming` (owners, persona names, same_goal
groups), :mod:`~pipeline.goals.feedback` (the four feedback kinds, one module each),
:mod:`~pipeline.goals.build` (selection + assembly; the goals stage's work), :mod:`~pipeline.goals.schema` (the editable
document), :mod:`~pipeline.goals.edits` (export / import), :mod:`~pipeline.goals.store` (``goals.zarr``
format tree and the :class:`Goals` reader), :mod:`~pipeline.goals.render` (pictures).
"""
