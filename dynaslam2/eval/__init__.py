"""Evaluation: trajectory metrics (evo's ATE/RPE definitions) and the metrics report of `dynaslam2 eval`."""
