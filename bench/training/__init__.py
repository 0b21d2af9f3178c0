"""Reports on training runs: test-split metrics and the MoSA-VQ ablation (torch)."""
