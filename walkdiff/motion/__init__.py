"""Motion files and geometry: BVH and glTF, skeletons and their profiles, rotations, the feature
representation, mirroring, resampling, paths, foot clean-up and `inspect`/`convert`. No models, no datasets,
no Lightning."""
