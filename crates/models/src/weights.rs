//! Finding and opening model weights in a local Hugging Face / diffusers folder.
//!
//! Every model in this crate is loaded the same way: a folder (or a component
//! sub-folder such as `unet/`) holding `config.json` and safetensors weights. Weights
//! are memory-mapped, never copied into a buffer first, and converted to the compute
//! dtype (f32 on CPU) tensor by tensor as the model is built, so fp32, fp16 and bf16
//! files all load. A missing folder or file is an [`Error`] that names the folder, the
//! file expected, and the `hf download ...` command that fetches it. The benchmarks
//! build models with random weights instead (`random_weights`).

use std::path::{Path, PathBuf};

use candle_core::{DType, Device};
use candle_nn::{VarBuilder, VarMap};

use crate::check::ModelConfig;

/// What went wrong while locating or opening weights.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The folder itself is missing.
    #[error("{what}: folder {} not found; get it with `{hint}`", path.display())]
    MissingFolder { what: String, path: PathBuf, hint: String },
    /// A file the model needs is missing from an existing folder.
    #[error("{what}: {} has no {expected}; get it with `{hint}`", dir.display())]
    MissingFile { what: String, dir: PathBuf, expected: String, hint: String },
    /// A file exists but cannot be used (bad JSON, bad safetensors header, wrong shapes...).
    #[error("{}: {msg}", path.display())]
    Corrupt { path: PathBuf, msg: String },
    /// An error from the tensor library while building or running a model.
    #[error(transparent)]
    Candle(#[from] candle_core::Error),
}

/// A model folder: where it is, what it is for and how a user gets it.
#[derive(Debug, Clone)]
pub struct ModelDir {
    /// The folder (a component sub-folder for diffusers pipelines).
    pub path: PathBuf,
    /// Human name used in messages, e.g. "InstructPix2Pix UNet".
    pub what: String,
    /// The command that downloads the weights, e.g. `hf download timbrooks/instruct-pix2pix --local-dir DIR`.
    pub hint: String,
}

/// Weight file stems tried in order: full precision first, then half-precision variants.
const VARIANTS: [&str; 3] = ["", ".fp16", ".bf16"];

impl ModelDir {
    /// A model folder that must exist.
    pub fn open(path: &Path, what: &str, hint: &str) -> Result<Self, Error> {
        let dir = Self { path: path.to_path_buf(), what: what.to_string(), hint: hint.to_string() };
        if !path.is_dir() {
            return Err(Error::MissingFolder { what: dir.what, path: dir.path, hint: dir.hint });
        }
        Ok(dir)
    }

    /// A component sub-folder (`unet`, `vae`, `text_encoder`, `tokenizer`) of a pipeline folder.
    pub fn component(&self, name: &str, what: &str) -> Result<Self, Error> {
        Self::open(&self.path.join(name), what, &self.hint)
    }

    fn missing(&self, expected: &str) -> Error {
        Error::MissingFile {
            what: self.what.clone(),
            dir: self.path.clone(),
            expected: expected.to_string(),
            hint: self.hint.clone(),
        }
    }

    /// Parses `name` (usually `config.json`) in this folder as JSON, unchecked.
    pub fn json(&self, name: &str) -> Result<serde_json::Value, Error> {
        let path = self.path.join(name);
        let text = std::fs::read_to_string(&path).map_err(|_| self.missing(name))?;
        serde_json::from_str(&text).map_err(|e| Error::Corrupt { path, msg: format!("invalid JSON: {e}") })
    }

    /// Parses `name` (usually `config.json`) in this folder and checks it field by field
    /// ([`ModelConfig::check`]); a problem is an error naming the file and the field.
    pub fn config<T: ModelConfig>(&self, name: &str) -> Result<T, Error> {
        self.checked(name, self.json(name)?)
    }

    /// `value` (read from `name` in this folder, or a part of it) as a checked config.
    pub fn checked<T: ModelConfig>(&self, name: &str, value: serde_json::Value) -> Result<T, Error> {
        let path = self.path.join(name);
        let config: T = serde_json::from_value(value)
            .map_err(|e| Error::Corrupt { path: path.clone(), msg: format!("invalid config: {e}") })?;
        config.check().map_err(|msg| Error::Corrupt { path, msg })?;
        Ok(config)
    }

    /// Runs `build` (a model constructor reading this folder's weights) and turns the
    /// tensor library's errors into one line naming this folder: a tensor whose shape in
    /// the weights differs from the one the config implies names the tensor and both
    /// shapes; a missing tensor is named; no backtrace is printed.
    pub fn build<T>(&self, build: impl FnOnce() -> Result<T, Error>) -> Result<T, Error> {
        build().map_err(|e| match e {
            Error::Candle(e) => Error::Corrupt { path: self.path.clone(), msg: weights_mismatch(e) },
            other => other,
        })
    }

    /// The path of a file that must exist in this folder.
    pub fn file(&self, name: &str) -> Result<PathBuf, Error> {
        let path = self.path.join(name);
        if path.is_file() {
            Ok(path)
        } else {
            Err(self.missing(name))
        }
    }

    /// The safetensors files holding the weights named `stem` (`model` for transformers,
    /// `diffusion_pytorch_model` for diffusers): `stem.safetensors`, its `.fp16` / `.bf16`
    /// variants, or the shards listed by `stem.safetensors.index.json`.
    pub fn safetensors(&self, stem: &str) -> Result<Vec<PathBuf>, Error> {
        for variant in VARIANTS {
            let single = self.path.join(format!("{stem}{variant}.safetensors"));
            if single.is_file() {
                return Ok(vec![single]);
            }
            let index = self.path.join(format!("{stem}.safetensors{variant}.index.json"));
            let index = if index.is_file() {
                index
            } else {
                self.path.join(format!("{stem}{variant}.safetensors.index.json"))
            };
            if index.is_file() {
                return self.shards(&index);
            }
        }
        if self.path.join(format!("{stem}.bin")).is_file() {
            return Err(Error::Corrupt {
                path: self.path.join(format!("{stem}.bin")),
                msg: "PyTorch pickle weights are not supported; download the safetensors files \
                      (they are in the same Hugging Face repository)"
                    .to_string(),
            });
        }
        Err(self.missing(&format!("{stem}.safetensors")))
    }

    fn shards(&self, index: &Path) -> Result<Vec<PathBuf>, Error> {
        #[derive(serde::Deserialize)]
        struct Index {
            weight_map: std::collections::BTreeMap<String, String>,
        }
        let text = std::fs::read_to_string(index)
            .map_err(|e| Error::Corrupt { path: index.to_path_buf(), msg: e.to_string() })?;
        let parsed: Index = serde_json::from_str(&text)
            .map_err(|e| Error::Corrupt { path: index.to_path_buf(), msg: format!("invalid JSON: {e}") })?;
        let mut files: Vec<&String> = parsed.weight_map.values().collect();
        files.sort();
        files.dedup();
        files.into_iter().map(|f| self.file(f)).collect()
    }

    /// Memory-maps the weights named `stem` and returns a builder that converts every
    /// tensor to `dtype` on `device` as it is fetched.
    pub fn var_builder(
        &self,
        stem: &str,
        dtype: DType,
        device: &Device,
    ) -> Result<VarBuilder<'static>, Error> {
        let files = self.safetensors(stem)?;
        for f in &files {
            check_safetensors_header(f)?;
        }
        // SAFETY: the files are opened read-only and mapped for the lifetime of the
        // builder; like every memory-mapped loader, this assumes nobody truncates them
        // while the model is loading.
        unsafe { VarBuilder::from_mmaped_safetensors(&files, dtype, device) }.map_err(|e| Error::Corrupt {
            path: files[0].clone(),
            msg: format!("not a readable safetensors file: {e}"),
        })
    }
}

/// One line for a tensor-library error raised while building a model from weights.
fn weights_mismatch(e: candle_core::Error) -> String {
    use candle_core::Error as C;
    match e {
        C::WithBacktrace { inner, .. } => weights_mismatch(*inner),
        C::UnexpectedShape { msg, expected, got } => {
            let name = msg.strip_prefix("shape mismatch for ").unwrap_or(&msg);
            format!(
                "tensor {name} has shape {:?} in the weights but the config implies {:?}: \
                 config.json does not match these weights",
                got.dims(),
                expected.dims()
            )
        }
        C::CannotFindTensor { path } => {
            format!("the weights have no tensor {path}: config.json does not match these weights")
        }
        other => other.to_string().lines().next().unwrap_or_default().to_string(),
    }
}

/// Validates the safetensors header (length prefix and JSON) before mapping, so a
/// truncated or foreign file gives a message naming it rather than a library error.
fn check_safetensors_header(path: &Path) -> Result<(), Error> {
    use std::io::Read;
    let corrupt = |msg: String| Error::Corrupt { path: path.to_path_buf(), msg };
    let mut f = std::fs::File::open(path).map_err(|e| corrupt(e.to_string()))?;
    let len = f.metadata().map_err(|e| corrupt(e.to_string()))?.len();
    let mut prefix = [0u8; 8];
    f.read_exact(&mut prefix).map_err(|_| corrupt("too short to be a safetensors file".into()))?;
    let header = u64::from_le_bytes(prefix);
    if header == 0 || header > len.saturating_sub(8) || header > 100 << 20 {
        return Err(corrupt(format!(
            "safetensors header length {header} does not fit the file ({len} bytes)"
        )));
    }
    let mut json = vec![0u8; header as usize];
    f.read_exact(&mut json).map_err(|_| corrupt("truncated safetensors header".into()))?;
    let value: serde_json::Value =
        serde_json::from_slice(&json).map_err(|e| corrupt(format!("safetensors header is not JSON: {e}")))?;
    // Every tensor's data must lie inside the file.
    let data_len = len - 8 - header;
    if let Some(map) = value.as_object() {
        for (name, entry) in map {
            if name == "__metadata__" {
                continue;
            }
            let end = entry.get("data_offsets").and_then(|o| o.get(1)).and_then(|v| v.as_u64());
            match end {
                Some(end) if end <= data_len => {}
                _ => {
                    return Err(corrupt(format!("tensor {name} lies outside the file (truncated download?)")))
                }
            }
        }
    }
    Ok(())
}

/// The device models run on: CUDA device 0 when built with the `cuda` feature and a GPU
/// is present, the CPU otherwise.
pub fn default_device() -> Device {
    #[cfg(feature = "cuda")]
    if let Ok(d) = Device::new_cuda(0) {
        return d;
    }
    Device::Cpu
}

/// Random weights for a model built by `build`: a first build creates the randomly
/// initialised variables, and the returned builder holds detached copies of them.
/// Operations on variables record the graph for back-propagation and would keep every
/// activation alive; weights loaded from files are plain tensors, like these.
pub fn random_weights(
    device: &Device,
    build: impl FnOnce(VarBuilder) -> Result<(), Error>,
) -> Result<VarBuilder<'static>, Error> {
    let map = VarMap::new();
    build(VarBuilder::from_varmap(&map, DType::F32, device))?;
    let tensors: std::collections::HashMap<String, candle_core::Tensor> = map
        .data()
        .lock()
        .map_err(|_| candle_core::Error::Msg("poisoned weight map".into()))?
        .iter()
        .map(|(k, v)| (k.clone(), v.as_tensor().detach()))
        .collect();
    Ok(VarBuilder::from_tensors(tensors, DType::F32, device))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn missing_folder_names_it_and_the_download_command() {
        let err =
            ModelDir::open(Path::new("/nonexistent/ip2p"), "InstructPix2Pix", "hf download x --local-dir y")
                .unwrap_err()
                .to_string();
        assert!(err.contains("/nonexistent/ip2p") && err.contains("hf download x"), "{err}");
    }

    #[test]
    fn missing_and_truncated_weights_are_named() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = ModelDir::open(tmp.path(), "CLIP", "hf download openai/clip").unwrap();
        let err = dir.safetensors("model").unwrap_err().to_string();
        assert!(err.contains("model.safetensors") && err.contains("hf download"), "{err}");

        // A header that promises more data than the file holds.
        let header = br#"{"w":{"dtype":"F32","shape":[4],"data_offsets":[0,16]}}"#;
        let mut bytes = (header.len() as u64).to_le_bytes().to_vec();
        bytes.extend_from_slice(header);
        bytes.extend_from_slice(&[0u8; 8]);
        std::fs::write(tmp.path().join("model.safetensors"), &bytes).unwrap();
        let err = dir.var_builder("model", DType::F32, &Device::Cpu).err().unwrap().to_string();
        assert!(err.contains("model.safetensors") && err.contains("outside the file"), "{err}");

        std::fs::write(tmp.path().join("model.safetensors"), b"garbage").unwrap();
        let err = dir.var_builder("model", DType::F32, &Device::Cpu).err().unwrap().to_string();
        assert!(err.contains("too short"), "{err}");
    }

    #[test]
    fn half_precision_variant_is_found() {
        let tmp = tempfile::tempdir().unwrap();
        std::fs::write(tmp.path().join("diffusion_pytorch_model.fp16.safetensors"), b"").unwrap();
        let dir = ModelDir::open(tmp.path(), "UNet", "hf").unwrap();
        let files = dir.safetensors("diffusion_pytorch_model").unwrap();
        assert!(files[0].ends_with("diffusion_pytorch_model.fp16.safetensors"));
    }
}
