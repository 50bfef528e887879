"""Retargeting: a clip played by another humanoid rig. Rest poses aligned per bone, the feet on the
source's path, the built-in target rigs, `TargetRig` (the rig `--to` and `to=` name), `Take` (generated
motion in hand, which can be played on such a rig) and `walkdiff retarget` / `convert --to`. Above
`motion` (skeletons, profiles, the humanoid map), below everything that writes motion."""
