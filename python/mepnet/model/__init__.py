"""The MEPNet detector (stage 1): model, targets, losses and decoding.

``config`` holds :class:`ModelConfig` (``slim`` for CPUs, ``paper`` for GPUs); ``net`` the
network; ``targets`` turns a manual step into tensors; ``losses`` the training objective;
``decode`` turns network outputs into detections for stage 2 (a :class:`Predictor`).
"""
