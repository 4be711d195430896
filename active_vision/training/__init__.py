"""The lab that makes the perception artefacts: it renders data, trains and calibrates the
networks, and measures them. Nothing in the product (the daemon, the envs, the supervisor)
imports it; it imports the product.

- ``python -m active_vision.training.dataset``: render labelled frames from the worlds.
- ``python -m active_vision.training.train``: train (and calibrate) the perception network.
- ``python -m active_vision.training.predict_train``: train the predictive heatmap.
- ``python -m active_vision.training.evaluate``: quality figures on a split.
- ``python -m active_vision.training.calibrate``: choose the heatmap threshold on validation.
"""
