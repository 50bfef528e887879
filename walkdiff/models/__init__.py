"""The LightningModules and their networks: the styled GAN-DDPM, DiffMotion and the path walker, the motion
and action evaluators. They import no task: what uses them sits above."""
