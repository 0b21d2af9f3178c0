"""Quality of a bundle: the evaluator, the standard metrics, semantic checks (no torch)."""
