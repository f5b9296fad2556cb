"""One module per pipeline stage, each defining ``STAGE`` (:class:`ident.pipeline.stage.Stage`)."""
