"""The reconstruction pipeline: static fit -> anchors -> refine -> v0 -> dynamics -> predict."""
