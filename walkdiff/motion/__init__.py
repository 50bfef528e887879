"""Motion files and geometry: BVH and glTF, skeletons and their profiles, rotations, the feature
representation, mirroring, resampling, paths, foot clean-up, the humanoid map and `inspect`/`convert`
(`convert --to` and all retargeting are in `walkdiff.retarget`). No models, no datasets, no Lightning."""
