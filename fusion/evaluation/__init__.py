"""Evaluation: orientation and trajectory error metrics, synthetic runs with ground truth
(:mod:`.synthetic`, kinematic; :mod:`.physics_sim`, an independent 1 kHz physics simulator),
and the baselines the fused odometry has to beat (:mod:`.baselines`)."""
