"""The run's human-readable outputs: images, videos, plots and point clouds (`media`), the
self-contained report.html and its sections (`html`), and the verdict on what the scores say
(`verdict`). The pipeline, the posterior and the diagnosis each add sections."""
