"""What is compared with the images: frame targets and the ground (`targets`), coarser and finer
views (`images`), silhouettes against projected points (`silhouette`) and ground contact
(`contact`). Used by the identification, the posterior, the diagnosis and the baselines."""
