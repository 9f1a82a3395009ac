"""Orchestration: the run's plan, the runner's stages, resume and its ledgers,
changes between runs, workflows, and the cluster.

Named ``runs``, not ``run``: a subpackage ``pipeline.run`` would replace the
public function ``pipeline.run`` as an attribute of the package once imported.
"""
