"""The prediction networks (PyTorch): :mod:`~nudge_train.models.config` (their sizes, the
teacher's and student's configurations), :mod:`~nudge_train.models.networks` (the Social-GAN
generator and discriminator, ``build_model``) and :mod:`~nudge_train.models.interactive` (the
teacher's and student's interactive prediction, the reference the Rust predictor reproduces)."""
