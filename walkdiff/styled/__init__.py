"""The styled window GAN-DDPM at work: sampling, style transfer, long motion and few-step distillation."""
