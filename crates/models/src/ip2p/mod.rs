//! InstructPix2Pix. Being written.
