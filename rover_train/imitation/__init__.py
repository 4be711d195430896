"""The lab that makes the zoo's entries: the privileged planner expert
(:mod:`~rover_train.imitation.expert`), the DAgger engine
(:mod:`~rover_train.imitation.dagger`), the entry recipes and their command
(:mod:`~rover_train.imitation.distill`), the zoo's evaluation
(:mod:`~rover_train.imitation.zoo_eval`) and the main job (:mod:`~rover_train.imitation.demo`).
Nothing in the product (the envs, ``rover-train``, ``zoo.load``) imports it.
"""
