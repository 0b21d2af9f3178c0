"""mogo.export: the torch side. Rooms, each importing only the ones before it:
data (numpy: corpus, HumanML3D files, metrics) -> models (torch modules, run checkpoints)
-> onnx (graphs and bundles) -> train (training loops) -> cli (the training verbs)."""
