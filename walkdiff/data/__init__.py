"""Motion datasets: Xia, HumanAct12 and any folder of BVH files as sources, `data scan` (a folder -> a
config), feature caches, and the Lightning data modules (windows for the styled model, takes for speech)."""
