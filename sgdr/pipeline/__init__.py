"""The reconstruction pipeline's orchestration: the table of stages (`run`), what each stage
produces and loads (`flow`), the resumable stage runner (`stages`), the prediction (`predict`),
the asset (`asset`) and the run's human-readable outputs (`report`); config group `recon`."""
