"""Detection on the simulator side: labelled datasets and evaluation against the world's ground truth.

Everything here needs the world (``Scan`` ground truth, ``Scene`` geometry); the detectors themselves
(:mod:`detectors`) never import ``kin_envs`` and run on any 2D scan, simulated or recorded.

- :mod:`kin_envs.detection.dataset`: seeded scenes -> segmented, featurised, labelled samples.
- :mod:`kin_envs.detection.evaluation`: kin ground truth of a scan, matching, P / R / F1 tables.
- :mod:`kin_envs.detection.seeds`: which seeds training data may use (``check_training_seeds``: never
  the benchmark's reserved seeds; ``within=TRAINING_SEEDS`` for the swarm-trained beam data).
"""
