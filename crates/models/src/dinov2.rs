//! DINOv2 patch features (HF `Dinov2Model` layout). Being written.
