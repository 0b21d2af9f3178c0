"""The default recipes of `mogo train vq`, `t2m` and `evaluator`: what defines a run, fixed at
its start and taken from the checkpoint on --resume. Torch-free, so the CLI can show them."""

VQ_MODEL_SWITCHES = ("levels", "down_factor", "causal", "scale_bias", "decorrelation")
# The model switches (None: the preset's value) exist for ablations.
VQ_RECIPE = dict(preset="cpu_default", batch_size=64, lr=2e-4, warmup=1000, seed=0,
                 crop_frames=64, whole_clips=False, weight_average=None,
                 **{name: None for name in VQ_MODEL_SWITCHES}, init=None, tune="all")
# whole_clips: train on whole clips batched by length instead of crops of crop_frames;
# weight_average: the decay of an exponential moving average of the weights, which validation
# measures and best.pt keeps (None: off);
# init: the checkpoint (or bundle) a fine-tuning run (`--init`) started from, None for a run
# from scratch; tune: "all" weights, or "decoder" alone (the encoder and codebooks, so the
# tokens, stay).
T2M_RECIPE = dict(preset="cpu_default", batch_size=32, lr=2e-4, warmup=1000, seed=0,
                  text_encoder="small")
EVALUATOR_RECIPE = dict(preset="cpu_default", batch_size=64, lr=3e-4, warmup=200, seed=0)
