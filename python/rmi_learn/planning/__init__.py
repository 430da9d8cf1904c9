"""Planning with a policy and a world model: sample action chunks, score them, select, refine.

Modules: :mod:`~rmi_learn.planning.standardiser` (the training standardisation as tensors),
:mod:`~rmi_learn.planning.cost` (the paper's combined cost J),
:mod:`~rmi_learn.planning.scorers` (world models as scorers, ensembles, the costs of chunks),
:mod:`~rmi_learn.planning.planner` (K samples ranked by a scorer),
:mod:`~rmi_learn.planning.refine` (gradient refinement of a chunk toward a water goal),
:mod:`~rmi_learn.planning.realtime` (the planner on the fast sampling path),
:mod:`~rmi_learn.planning.policy` (a trained policy as one object: :func:`load_policy`,
:class:`Policy`) and :mod:`~rmi_learn.planning.ranking` (the ranking stage, ``rmi rank``).
"""

from rmi_learn.planning.policy import Policy, load_policy

__all__ = ["Policy", "load_policy"]
