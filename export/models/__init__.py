"""The torch models: MoSA-VQ, RQHC-Transformer, text encoders, the evaluator."""
