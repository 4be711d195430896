"""The lab that makes the zoo's entries: the privileged planner expert
(:mod:`~rover_train.imitation.expert`), the DAgger engine
(:mod:`~rover_train.imitation.dagger`), the entry recipes and their command
(:mod:`~rover_train.imitation.distill`), the planner expert as an evaluation agent
(:mod:`~rover_train.imitation.expert_agent`, which ``rover-eval ENTRY --expert`` loads as a
plugin), what looking is worth to the teachers and students
(:mod:`~rover_train.imitation.gaze_value`, run by ``benchmarks/gaze_value.py``) and the main
job (:mod:`~rover_train.imitation.demo`).
Nothing in the product (the envs, ``rover-train``, ``zoo.load``) imports it.
"""
