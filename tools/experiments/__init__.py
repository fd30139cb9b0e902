"""`occloc experiments`: the thesis's chapter 6 sweeps redone end to end with the synthetic
camera (`tools.synth`) and the whole receiver (`receiver.pipeline.Receiver`).

Each experiment (`tools.experiments.registry.EXPERIMENTS`) sweeps one parameter of the thesis's
Table 2, renders every point (`tools.experiments.cache`: renders are stored by a hash of their
parameters), runs the receiver on it (`tools.experiments.receive`) and measures against the
renderer's truth. `tools.experiments.report` writes NAME.csv, NAME.png and summary.md.
"""
