"""The procedural corpus, HumanML3D-layout files and the quality metrics: numpy only."""
