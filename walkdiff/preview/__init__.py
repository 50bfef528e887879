"""Pictures of motion: stills, GIF/MP4 previews, the 3-D page of `walkdiff view`, the headless browser."""
