"""The reconstruction pipeline's orchestration: the table of stages and the dynamic models
(`run`), what each stage produces and loads (`flow`, `baselines_flow`), the resumable stage
runner and its caching (`stages`). Run folders are `sgdr.run_folder`; the asset and its
prediction `sgdr.asset`; the report `sgdr.report`; config group `recon` (`sgdr.identify.config`)."""
