"""Training: the loop and the VQ, transformer and evaluator trainers (torch)."""
