"""Motion maths and motion files, numpy only: the skeletons, quaternions, HumanML3D features
<-> joints, mirroring, BVH and stick-figure GIFs. Nothing here knows about models."""
