//! CLIP image and text features (HF `CLIPModel` layout). Being written.
