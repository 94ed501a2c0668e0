"""A dataset project of its own: a git + DVC repository holding ``params.yaml``, ``dvc.yaml``, the manifests and the
dataset card, versioned with git tags and DVC remotes, outside zipon's source tree.

:mod:`pipeline.project.init` creates one (``zipon init``), :mod:`pipeline.project.card` writes the card of a
version (``zipon card``, refreshed by ``zipon run``), :mod:`pipeline.project.diff` compares two versions
(``zipon diff``) from git alone.
"""
