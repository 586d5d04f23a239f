//! [`WithSemantic`]: any editor with its semantic features E_v replaced by a feature model
//! (DINOv2 when `--dino-weights` is given), so the edited views and the source renders
//! use the same extractor.

use crate::{EditedView, Editor, Error, SourceView};

/// Semantic features of an `H × W × 3` image: `(H × W × d, d)`.
pub type SemanticModel<'a> = dyn Fn(&[f32], usize, usize) -> Result<(Vec<f32>, usize), Error> + 'a;

/// Wraps an editor and recomputes E_v of every edited view from its edited image.
pub struct WithSemantic<'a> {
    inner: Box<dyn Editor + 'a>,
    features: Box<SemanticModel<'a>>,
}

impl<'a> WithSemantic<'a> {
    pub fn new(inner: Box<dyn Editor + 'a>, features: Box<SemanticModel<'a>>) -> Self {
        Self { inner, features }
    }
}

impl Editor for WithSemantic<'_> {
    fn name(&self) -> &str {
        self.inner.name()
    }

    fn edit(&mut self, views: &[SourceView], prompt: &str) -> Result<Vec<Option<EditedView>>, Error> {
        let mut out = self.inner.edit(views, prompt)?;
        for v in out.iter_mut().flatten() {
            let EditedView { image, width, height, .. } = &*v;
            let (semantic, d) = (self.features)(image, *width, *height)?;
            if semantic.len() != width * height * d {
                return Err(Error::Invalid(format!(
                    "semantic features of {} values for a {width}x{height} view with {d} channels",
                    semantic.len()
                )));
            }
            v.semantic = semantic;
            v.d_sem = d;
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Returns the source image unchanged with one-channel zero features.
    struct Identity;

    impl Editor for Identity {
        fn name(&self) -> &str {
            "identity"
        }
        fn edit(&mut self, views: &[SourceView], _: &str) -> Result<Vec<Option<EditedView>>, Error> {
            Ok(views
                .iter()
                .map(|v| {
                    let (width, height) = v.size();
                    Some(EditedView {
                        width,
                        height,
                        image: v.image.to_vec(),
                        semantic: vec![0.0; width * height],
                        d_sem: 1,
                        ..Default::default()
                    })
                })
                .collect())
        }
    }

    #[test]
    fn features_come_from_the_model_on_the_edited_image() {
        let cam = crate::folder::tests::camera("v", 3, 2);
        let image: Vec<f32> = (0..18).map(|i| i as f32 / 18.0).collect();
        let views = [SourceView { index: 0, camera: &cam, image: &image }];
        // Two channels: the red value and a constant.
        let model = |img: &[f32], w: usize, h: usize| -> Result<(Vec<f32>, usize), Error> {
            Ok((img.chunks(3).take(w * h).flat_map(|p| [p[0], 7.0]).collect(), 2))
        };
        let mut e = WithSemantic::new(Box::new(Identity), Box::new(model));
        assert_eq!(e.name(), "identity");
        let out = e.edit(&views, "x").unwrap();
        let v = out[0].as_ref().unwrap();
        assert_eq!(v.d_sem, 2);
        assert_eq!(v.semantic[..4], [0.0, 7.0, 3.0 / 18.0, 7.0]);

        let wrong =
            |_: &[f32], _: usize, _: usize| -> Result<(Vec<f32>, usize), Error> { Ok((vec![0.0; 5], 2)) };
        let mut e = WithSemantic::new(Box::new(Identity), Box::new(wrong));
        assert!(e.edit(&views, "x").is_err());
    }
}
