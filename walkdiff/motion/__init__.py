"""Motion geometry and files (BVH, skeleton, rotations, features); no Lightning here."""
