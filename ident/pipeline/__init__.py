"""The pipeline: one ordered list of stages (:func:`ident.pipeline.plan.plan`) and the plain
runner (:func:`ident.pipeline.stage.run_stages`); the study's resumable runner iterates the same
list (docs/architecture.md)."""
