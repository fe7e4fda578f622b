//! External label volumes (e.g. the FDA VICTRE breastPhantom output): raw
//! 8-bit labels described by a TOML sidecar.
//!
//! ```toml
//! raw = "pc_1_crop.raw.gz"            # path relative to the sidecar (gzip allowed)
//! dims = [331, 539, 258]             # file order, fastest-varying first
//! axes = ["depth", "lateral", "vertical"]
//! reversed = []                      # axes that run nipple->chest or top->bottom
//! voxel_mm = 0.2
//! [labels]                           # file label = tissue (air, adipose, skin,
//! 0 = "air"                          # fibroglandular, ligament)
//! 1 = "adipose"
//! ```
//! Every label in the file must be mapped; an unmapped one is an error naming
//! the label and its first voxel. This module decodes bytes; reading the files
//! is the adapter's job (`dbt-store`).

use crate::{LabelVolume, PhantomError};
use dbt_materials::Tissue;
use serde::Deserialize;
use std::collections::BTreeMap;

/// The named axes of a volume.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum VolumeAxis {
    /// Left-right, along the chest wall.
    Lateral,
    /// The compression axis, support to paddle.
    Vertical,
    /// Chest wall to nipple.
    Depth,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSidecar {
    raw: String,
    dims: Vec<usize>,
    axes: Vec<VolumeAxis>,
    #[serde(default)]
    reversed: Vec<VolumeAxis>,
    voxel_mm: f64,
    labels: BTreeMap<String, String>,
}

/// A parsed, validated sidecar.
#[derive(Debug, Clone, PartialEq)]
pub struct ExternalSidecar {
    /// The raw file, relative to the sidecar.
    pub raw: String,
    /// Dimensions in file order, fastest first.
    pub dims: [usize; 3],
    /// The meaning of each file axis, fastest first.
    pub axes: [VolumeAxis; 3],
    /// Axes stored in the opposite direction to ours.
    pub reversed: Vec<VolumeAxis>,
    /// Isotropic voxel side, mm.
    pub voxel_mm: f64,
    /// Tissue of each file label (unmapped labels are errors).
    pub labels: [Option<Tissue>; 256],
}

fn bad(msg: impl Into<String>) -> PhantomError {
    PhantomError::Sidecar(msg.into())
}

impl ExternalSidecar {
    /// Parse and validate a sidecar.
    pub fn from_toml_str(text: &str) -> Result<Self, PhantomError> {
        let r: RawSidecar = toml::from_str(text).map_err(|e| bad(e.to_string()))?;
        let dims: [usize; 3] = r
            .dims
            .clone()
            .try_into()
            .map_err(|_| bad(format!("`dims` needs 3 entries, got {}", r.dims.len())))?;
        if dims.contains(&0) {
            return Err(bad(format!(
                "`dims` = {dims:?}: every dimension must be positive"
            )));
        }
        let axes: [VolumeAxis; 3] = r
            .axes
            .clone()
            .try_into()
            .map_err(|_| bad(format!("`axes` needs 3 entries, got {}", r.axes.len())))?;
        for a in [VolumeAxis::Lateral, VolumeAxis::Vertical, VolumeAxis::Depth] {
            if !axes.contains(&a) {
                return Err(bad(format!(
                    "`axes` = {axes:?} must name each of lateral, vertical, depth once"
                )));
            }
        }
        if !(r.voxel_mm.is_finite() && r.voxel_mm > 0.0) {
            return Err(bad(format!("`voxel_mm` = {} must be positive", r.voxel_mm)));
        }
        if r.raw.trim().is_empty() {
            return Err(bad("`raw` is empty"));
        }
        let mut labels = [None; 256];
        for (k, v) in &r.labels {
            let code: u8 = k
                .trim()
                .parse()
                .map_err(|_| bad(format!("[labels] key `{k}` is not a label code 0..255")))?;
            let t = Tissue::from_name(v.trim()).ok_or_else(|| {
                bad(format!(
                    "[labels] {code} = \"{v}\": unknown tissue (air, adipose, skin, fibroglandular, ligament)"
                ))
            })?;
            labels[code as usize] = Some(t);
        }
        Ok(Self {
            raw: r.raw,
            dims,
            axes,
            reversed: r.reversed,
            voxel_mm: r.voxel_mm,
            labels,
        })
    }

    /// Decode raw bytes into a [`LabelVolume`] in our axis order, cropped to
    /// the tissue (the breast rests on vertical index 0).
    pub fn decode(&self, raw: &[u8]) -> Result<LabelVolume, PhantomError> {
        let n: usize = self.dims.iter().product();
        if raw.len() != n {
            return Err(PhantomError::Raw(format!(
                "`{}` holds {} bytes, dims {:?} need {n}",
                self.raw,
                raw.len(),
                self.dims
            )));
        }
        // Map labels first so an unmapped one is reported at its file voxel.
        let mut lut = [u8::MAX; 256];
        for (code, t) in self.labels.iter().enumerate() {
            if let Some(t) = t {
                lut[code] = t.label();
            }
        }
        if let Some(i) = raw.iter().position(|&l| lut[l as usize] == u8::MAX) {
            let voxel = [
                i % self.dims[0],
                (i / self.dims[0]) % self.dims[1],
                i / (self.dims[0] * self.dims[1]),
            ];
            return Err(PhantomError::Unmapped {
                label: raw[i],
                voxel,
            });
        }
        // Our order: lateral, vertical, depth. pos[a] = file axis of our axis a.
        let ours = [VolumeAxis::Lateral, VolumeAxis::Vertical, VolumeAxis::Depth];
        let pos = ours.map(|a| self.axes.iter().position(|&b| b == a).unwrap_or(0));
        let out_dims = pos.map(|p| self.dims[p]);
        let stride_file = [1, self.dims[0], self.dims[0] * self.dims[1]];
        let mut stride = pos.map(|p| stride_file[p] as isize);
        let mut start = 0isize;
        for (a, &ax) in ours.iter().enumerate() {
            if self.reversed.contains(&ax) {
                start += (out_dims[a] as isize - 1) * stride[a];
                stride[a] = -stride[a];
            }
        }
        let mut data = Vec::with_capacity(n);
        for d in 0..out_dims[2] {
            for v in 0..out_dims[1] {
                let base = start + d as isize * stride[2] + v as isize * stride[1];
                for l in 0..out_dims[0] {
                    let i = (base + l as isize * stride[0]) as usize;
                    data.push(lut[raw[i] as usize]);
                }
            }
        }
        LabelVolume::new(out_dims, self.voxel_mm, data)?.cropped_to_tissue()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = r#"
raw = "x.raw"
dims = [3, 2, 2]
axes = ["depth", "lateral", "vertical"]
voxel_mm = 0.5
[labels]
0 = "air"
1 = "adipose"
29 = "fibroglandular"
"#;

    #[test]
    fn decodes_axes_and_labels() {
        let s = ExternalSidecar::from_toml_str(GOOD).unwrap();
        // file index = depth + 3 * (lateral + 2 * vertical)
        let mut raw = vec![1u8; 12];
        raw[2 + 3 * (1 + 2)] = 29; // depth 2, lateral 1, vertical 1
        let v = s.decode(&raw).unwrap();
        assert_eq!(v.dims(), [2, 2, 3]);
        assert_eq!(v.at(1, 1, 2), Tissue::Fibroglandular.label());
        assert_eq!(v.at(0, 0, 0), Tissue::Adipose.label());
        // Reversed vertical axis flips it.
        let s2 = ExternalSidecar::from_toml_str(
            &GOOD.replace("voxel_mm", "reversed = [\"vertical\"]\nvoxel_mm"),
        )
        .unwrap();
        let v2 = s2.decode(&raw).unwrap();
        assert_eq!(v2.at(1, 0, 2), Tissue::Fibroglandular.label());
    }

    #[test]
    fn unmapped_label_names_label_and_voxel() {
        let s = ExternalSidecar::from_toml_str(GOOD).unwrap();
        let mut raw = vec![0u8; 12];
        raw[7] = 95;
        match s.decode(&raw) {
            Err(PhantomError::Unmapped { label, voxel }) => {
                assert_eq!(label, 95);
                assert_eq!(voxel, [1, 0, 1]);
            }
            other => panic!("{other:?}"),
        }
        assert!(matches!(s.decode(&raw[..11]), Err(PhantomError::Raw(_))));
    }

    #[test]
    fn bad_sidecars_are_named() {
        let cases = [
            (GOOD.replace("[3, 2, 2]", "[3, 2]"), "`dims` needs 3"),
            (GOOD.replace("[3, 2, 2]", "[3, 0, 2]"), "must be positive"),
            (
                GOOD.replace("\"depth\", ", "\"lateral\", "),
                "each of lateral",
            ),
            (GOOD.replace("\"vertical\"]", "\"up\"]"), "unknown variant"),
            (GOOD.replace("0.5", "-1"), "`voxel_mm`"),
            (GOOD.replace("29 =", "300 ="), "not a label code"),
            (
                GOOD.replace("\"fibroglandular\"", "\"bone\""),
                "unknown tissue",
            ),
            (GOOD.replace("raw = \"x.raw\"", ""), "missing field `raw`"),
            (format!("colour = 1\n{GOOD}"), "unknown field"),
        ];
        for (text, want) in cases {
            let e = ExternalSidecar::from_toml_str(&text)
                .unwrap_err()
                .to_string();
            assert!(e.contains(want), "expected `{want}` in `{e}`");
        }
    }
}
