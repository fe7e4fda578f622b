//! The external VICTRE set's documented compression (issue #48 point 5;
//! scripts/victre/README.md, "Compression"). EVALUATION ONLY.
//!
//! VICTRE compresses its breasts with a finite-element model (breastCompress
//! on FEBio 2); that route builds here but does not converge in reasonable
//! time on this project's machines, so the set is compressed by the
//! documented fallback: a volume-preserving geometric map of the
//! uncompressed label volume (breast tissue is nearly incompressible:
//! breastCompress itself gives fat and gland a Poisson's ratio of 0.49).
//!
//! Each vertical column of the breast (support to top, length `L`; the
//! tallest `H`) is squeezed to the height `T min(1, L / (k H))` with `T` the
//! compressed thickness and `k` the *contact fraction*: columns at least
//! `k H` long are flattened against the paddle, shorter ones (the periphery)
//! taper to the edge. Each column keeps its volume: squeezed by `L / top`,
//! it spreads over `L / top` times its area, outward from the chest wall's
//! centre along its own direction (in each thin wedge, `r'^2 = integral of
//! 2 (L / top) rho d rho`), so every tissue keeps its volume where it lies.
//! The skin at a column's two ends keeps its thickness (the interior
//! between takes the squeeze), as a real skin does under a paddle. The
//! pectoral muscle is cropped away first. `k = 1` is the affine map
//! (every column scaled by `T / H`, the plane by `sqrt(H / T)`: only the
//! tallest column touches the paddle, the top stays convex); smaller `k`
//! gives the flat contact zone of a compressed breast. `k` is a modelling choice, not fit to any breast
//! (scripts/victre/README.md). Labels are resampled by nearest neighbour
//! onto a cubic grid.

use thiserror::Error;

/// The generator's pectoral-muscle label.
pub const MUSCLE: u8 = 40;

/// The generator's skin label.
pub const SKIN: u8 = 2;

/// Why a volume cannot be compressed.
#[derive(Debug, Error, PartialEq)]
pub enum CompressError {
    /// The volume's size and dimensions disagree.
    #[error("{got} bytes for dims {dims:?} ({want} expected)")]
    Size {
        /// Bytes given.
        got: usize,
        /// The dims.
        dims: [usize; 3],
        /// Bytes they need.
        want: usize,
    },
    /// A number out of range.
    #[error("{what} = {value}: {why}")]
    Value {
        /// Which.
        what: &'static str,
        /// Its value.
        value: f64,
        /// What it must be.
        why: &'static str,
    },
    /// Nothing but air (or muscle).
    #[error("no breast tissue in front of the chest wall")]
    Empty,
}

/// A compressed volume: labels (the generator's codes), x (depth from the
/// chest wall) fastest, then y (lateral), then z (support to paddle).
#[derive(Debug, Clone, PartialEq)]
pub struct Compressed {
    /// `[nx, ny, nz]`.
    pub dims: [usize; 3],
    /// Voxel side, mm.
    pub voxel_mm: f64,
    /// The labels.
    pub labels: Vec<u8>,
    /// The uncompressed breast's height, mm.
    pub height_mm: f64,
    /// The chest-wall crop: voxels of depth removed (the muscle's).
    pub cropped_voxels: usize,
    /// The mean in-plane stretch (square root of the footprint's growth).
    pub stretch: f64,
}

/// The breast's vertical columns in front of the chest wall.
struct Columns {
    /// The chest wall: the first depth index in front of the muscle.
    crop: usize,
    /// Per column (x fastest, `nx * ny`): bottom voxel and length in voxels
    /// (0: no tissue).
    extent: Vec<(usize, usize)>,
    /// Per column: the skin runs at its bottom and top, voxels.
    skin: Vec<(usize, usize)>,
    /// The breast's lateral and vertical voxel ranges `[y0, y1, z0, z1]`
    /// (inclusive); `None` without tissue.
    bounds: Option<[usize; 4]>,
}

/// The columns of `labels` (`dims`, x fastest; its size checked by the
/// caller), the pectoral muscle cropped away.
fn columns(labels: &[u8], dims: [usize; 3]) -> Columns {
    let [nx, ny, nz] = dims;
    let at = |x: usize, y: usize, z: usize| labels[x + nx * (y + ny * z)];
    let crop = (0..nx)
        .rev()
        .find(|&x| (0..nz).any(|z| (0..ny).any(|y| at(x, y, z) == MUSCLE)))
        .map_or(0, |x| x + 1);
    let mut extent = vec![(0usize, 0usize); nx * ny];
    let mut skin = vec![(0usize, 0usize); nx * ny];
    let mut bounds: Option<[usize; 4]> = None;
    for y in 0..ny {
        for x in crop..nx {
            let Some(lo) = (0..nz).find(|&z| at(x, y, z) != 0) else {
                continue;
            };
            let hi = (lo..nz).rev().find(|&z| at(x, y, z) != 0).unwrap_or(lo);
            extent[x + nx * y] = (lo, hi - lo + 1);
            let bottom = (lo..=hi).take_while(|&z| at(x, y, z) == SKIN).count();
            let upper = if lo + bottom > hi {
                0
            } else {
                (lo..=hi).rev().take_while(|&z| at(x, y, z) == SKIN).count()
            };
            skin[x + nx * y] = (bottom, upper);
            let b = bounds.get_or_insert([y, y, lo, hi]);
            *b = [b[0].min(y), b[1].max(y), b[2].min(lo), b[3].max(hi)];
        }
    }
    Columns {
        crop,
        extent,
        skin,
        bounds,
    }
}

/// The uncompressed breast's height (support to top of its tissue in front
/// of the chest wall), mm; `None` for a volume without breast tissue.
pub fn height_mm(labels: &[u8], dims: [usize; 3], voxel_mm: f64) -> Option<f64> {
    if labels.len() != dims.iter().product::<usize>() {
        return None;
    }
    let [_, _, z0, z1] = columns(labels, dims).bounds?;
    Some((z1 - z0 + 1) as f64 * voxel_mm)
}

/// Compress `labels` (dims `[nx, ny, nz]`, x fastest, `voxel_mm` cubic;
/// x chest wall to nipple, y lateral, z inferior to superior) to
/// `thickness_mm` on a cubic grid of `out_voxel_mm`, columns from `contact`
/// times the tallest's length flattened against the paddle.
pub fn compress(
    labels: &[u8],
    dims: [usize; 3],
    voxel_mm: f64,
    thickness_mm: f64,
    out_voxel_mm: f64,
    contact: f64,
) -> Result<Compressed, CompressError> {
    let [nx, ny, nz] = dims;
    if labels.len() != nx * ny * nz {
        return Err(CompressError::Size {
            got: labels.len(),
            dims,
            want: nx * ny * nz,
        });
    }
    if !(contact > 0.0 && contact <= 1.0) {
        return Err(CompressError::Value {
            what: "contact",
            value: contact,
            why: "the contact fraction must be in (0, 1]",
        });
    }
    for (what, value) in [
        ("voxel_mm", voxel_mm),
        ("thickness_mm", thickness_mm),
        ("out_voxel_mm", out_voxel_mm),
    ] {
        if !(value.is_finite() && value > 0.0) {
            return Err(CompressError::Value {
                what,
                value,
                why: "must be a positive length",
            });
        }
    }
    let at = |x: usize, y: usize, z: usize| labels[x + nx * (y + ny * z)];
    let Columns {
        crop,
        extent: column,
        skin,
        bounds,
    } = columns(labels, dims);
    let [y0, y1, z0, z1] = bounds.ok_or(CompressError::Empty)?;
    let h = voxel_mm;
    let height = (z1 - z0 + 1) as f64 * h;
    if thickness_mm > height {
        return Err(CompressError::Value {
            what: "thickness_mm",
            value: thickness_mm,
            why: "thicker than the uncompressed breast",
        });
    }
    let full = contact * height / h; // columns this long touch the paddle
    let squeezed = |len: usize| thickness_mm * (len as f64 / full).min(1.0);
    // Whether a column keeps its skin's thickness (the interior between
    // takes the squeeze; a column too short for that is scaled whole), and
    // how much its area grows to keep its volume: the interior's where the
    // skin keeps its thickness.
    let keeps_skin = |len: usize, (bottom, upper): (usize, usize)| {
        let skins = (bottom + upper) as f64 * h;
        squeezed(len) > 2.0 * skins && len > bottom + upper
    };
    let spread = |len: usize, sk: (usize, usize)| {
        let skins = (sk.0 + sk.1) as f64 * h;
        if keeps_skin(len, sk) {
            (len as f64 * h - skins) / (squeezed(len) - skins)
        } else {
            len as f64 * h / squeezed(len)
        }
    };
    // In-plane coordinates (mm): u from the chest wall, v from the breast's
    // lateral centre. The column under a point, if any.
    let yc = 0.5 * (y0 + y1 + 1) as f64 * h;
    let column_at = |u: f64, v: f64| -> Option<(usize, usize, usize, usize)> {
        if u < 0.0 {
            return None;
        }
        let xi = crop + (u / h).floor() as usize;
        let y = v + yc;
        if y < 0.0 || xi >= nx {
            return None;
        }
        let yi = (y / h).floor() as usize;
        if yi >= ny {
            return None;
        }
        let (lo, len) = column[xi + nx * yi];
        (len > 0).then_some((xi, yi, lo, len))
    };
    // Each column keeps its volume: squeezed from L to `top`, it spreads
    // over L / top times its area. Radially from the chest wall's centre,
    // per direction: r'^2 = integral of 2 (L / top) rho d rho (mass
    // conservation in a thin wedge), where beyond the breast L / top = 1.
    const DIRECTIONS: usize = 721;
    let step = 0.5 * h;
    let reach = (((nx - crop) as f64 * h).powi(2) + (0.5 * ny as f64 * h + yc).powi(2)).sqrt();
    let samples = (reach / step).ceil() as usize + 1;
    let angle = |a: usize| {
        -std::f64::consts::FRAC_PI_2 + std::f64::consts::PI * a as f64 / (DIRECTIONS - 1) as f64
    };
    let mut radius = vec![0.0f64; DIRECTIONS * samples]; // r' at rho = k step
    let mut edge = vec![0.0f64; DIRECTIONS]; // the breast's r' per direction
    for a in 0..DIRECTIONS {
        let (sin, cos) = angle(a).sin_cos();
        let mut acc = 0.0;
        for k in 1..samples {
            let rho = (k as f64 - 0.5) * step;
            let inside = column_at(rho * cos, rho * sin);
            let q = inside.map_or(1.0, |(xi, yi, _, len)| spread(len, skin[xi + nx * yi]));
            acc += 2.0 * q * rho * step;
            if inside.is_some() {
                edge[a] = acc.sqrt();
            }
            radius[a * samples + k] = acc.sqrt();
        }
    }
    let o = out_voxel_mm;
    let (mut umax, mut vmin, mut vmax) = (0.0f64, 0.0f64, 0.0f64);
    for (a, &r) in edge.iter().enumerate() {
        let (sin, cos) = angle(a).sin_cos();
        umax = umax.max(r * cos);
        vmin = vmin.min(r * sin);
        vmax = vmax.max(r * sin);
    }
    let onx = (umax / o).ceil() as usize + 1;
    let ony = ((vmax - vmin) / o).ceil() as usize + 1;
    let onz = (thickness_mm / o).round().max(1.0) as usize;
    let mut out = vec![0u8; onx * ony * onz];
    for j in 0..ony {
        let vp = vmin + (j as f64 + 0.5) * o;
        for i in 0..onx {
            let up = (i as f64 + 0.5) * o;
            let rp = up.hypot(vp);
            let th = vp.atan2(up);
            let a = (((th + std::f64::consts::FRAC_PI_2) / std::f64::consts::PI)
                * (DIRECTIONS - 1) as f64)
                .round()
                .clamp(0.0, (DIRECTIONS - 1) as f64) as usize;
            if rp > edge[a] {
                continue;
            }
            let row = &radius[a * samples..(a + 1) * samples];
            // The input radius whose r' is rp (r' increases with rho).
            let k = row.partition_point(|&r| r < rp).clamp(1, samples - 1);
            let (r0, r1) = (row[k - 1], row[k]);
            let frac = if r1 > r0 { (rp - r0) / (r1 - r0) } else { 0.0 };
            let rho = (k as f64 - 1.0 + frac) * step;
            let (sin, cos) = th.sin_cos();
            let Some((xi, yi, lo, len)) = column_at(rho * cos, rho * sin) else {
                continue;
            };
            // The column's height after compression, from the support.
            let top = squeezed(len);
            let (bottom, upper) = skin[xi + nx * yi];
            let skins = (bottom + upper) as f64 * h;
            let keep_skin = keeps_skin(len, (bottom, upper));
            for kz in 0..onz {
                let zc = (kz as f64 + 0.5) * o;
                if zc >= top {
                    break;
                }
                let z = if !keep_skin {
                    lo as f64 * h + zc * len as f64 * h / top
                } else if zc < bottom as f64 * h {
                    lo as f64 * h + zc
                } else if zc >= top - upper as f64 * h {
                    (lo + len) as f64 * h - (top - zc)
                } else {
                    let inner = (len - bottom - upper) as f64 * h;
                    (lo + bottom) as f64 * h + (zc - bottom as f64 * h) * inner / (top - skins)
                };
                let zi = ((z / h).floor() as usize).clamp(lo, lo + len - 1);
                out[i + onx * (j + ony * kz)] = at(xi, yi, zi);
            }
        }
    }
    // The mean in-plane stretch, sqrt(area after / area before).
    let area_before = column.iter().filter(|&&(_, l)| l > 0).count() as f64 * h * h;
    let area_after = (0..onx * ony)
        .filter(|&p| (0..onz).any(|k| out[p + onx * ony * k] != 0))
        .count() as f64
        * o
        * o;
    let s = (area_after / area_before).sqrt();
    Ok(Compressed {
        dims: [onx, ony, onz],
        voxel_mm: o,
        labels: out,
        height_mm: height,
        cropped_voxels: crop,
        stretch: s,
    })
}

/// phantoms/victre-pc1.toml, whose label map (its last section, with the
/// modelling choices written beside it) every VICTRE breast is read with.
const PC1_SIDECAR: &str = include_str!("../../phantoms/victre-pc1.toml");

/// The sidecar `dbt_store::load_external_phantom` reads a compressed
/// breast through: the raw file `raw` (relative to the sidecar), its
/// dimensions and voxel, VICTRE's axes, and the label map of
/// phantoms/victre-pc1.toml.
pub fn sidecar(c: &Compressed, raw: &str, provenance: &str) -> String {
    let [nx, ny, nz] = c.dims;
    let labels = PC1_SIDECAR
        .find("[labels]")
        .map_or("", |i| &PC1_SIDECAR[i..]);
    format!(
        "# {provenance}\n\
         # EVALUATION ONLY: never train or tune on it.\n\
         raw = \"{raw}\"\n\
         dims = [{nx}, {ny}, {nz}]\n\
         axes = [\"depth\", \"lateral\", \"vertical\"]\n\
         voxel_mm = {}\n\
         # The label map of phantoms/victre-pc1.toml.\n\
         {labels}",
        c.voxel_mm
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A half-ellipsoid breast (fat with a glandular core and a skin shell)
    /// in front of a muscle slab, z up from the support.
    fn breast() -> (Vec<u8>, [usize; 3]) {
        let dims = [60, 80, 70];
        let mut v = vec![0u8; dims[0] * dims[1] * dims[2]];
        for z in 0..dims[2] {
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    let i = x + dims[0] * (y + dims[1] * z);
                    if x < 6 {
                        v[i] = MUSCLE;
                        continue;
                    }
                    let (u, w, t) = (
                        (x as f64 + 0.5 - 6.0) / 50.0,
                        (y as f64 + 0.5 - 40.0) / 35.0,
                        (z as f64 + 0.5 - 35.0) / 30.0,
                    );
                    let r = u * u + w * w + t * t;
                    if r < 1.0 {
                        v[i] = if r > 0.85 {
                            2
                        } else if r < 0.2 {
                            29
                        } else {
                            1
                        };
                    }
                }
            }
        }
        (v, dims)
    }

    /// The muscle is cropped, the compressed breast is `T` thick, and each
    /// tissue under the skin keeps its volume (nearest-neighbour resampling
    /// costs about a percent), the skin keeps its thickness (so its volume
    /// grows with the breast's footprint).
    #[test]
    fn compression_keeps_each_tissue_volume_and_reaches_the_thickness() {
        let (v, dims) = breast();
        let c = compress(&v, dims, 0.5, 15.0, 0.5, 1.0).unwrap();
        assert_eq!(c.cropped_voxels, 6);
        assert!((c.height_mm - 30.0).abs() < 0.51, "{}", c.height_mm);
        assert_eq!(height_mm(&v, dims, 0.5), Some(c.height_mm));
        assert_eq!(c.dims[2], 30);
        assert!(!c.labels.contains(&MUSCLE));
        let count = |l: &[u8], t: u8| l.iter().filter(|&&x| x == t).count() as f64;
        for t in [1u8, 29] {
            let (a, b) = (count(&v, t), count(&c.labels, t));
            assert!((b / a - 1.0).abs() < 0.03, "label {t}: {a} -> {b}");
        }
        assert!(count(&c.labels, SKIN) > 1.2 * count(&v, SKIN));
        // The skin at the top of the thickest column (at the chest wall,
        // mid-breast): as thick as it was.
        let n = c.dims[0] * c.dims[1];
        let centre = c.dims[0] * (c.dims[1] / 2);
        let top_skin = (0..c.dims[2])
            .rev()
            .skip_while(|&k| c.labels[centre + n * k] == 0)
            .take_while(|&k| c.labels[centre + n * k] == SKIN)
            .count();
        let col = |z: usize| v[6 + dims[0] * (40 + dims[1] * z)];
        let orig = (0..dims[2])
            .rev()
            .skip_while(|&z| col(z) == 0)
            .take_while(|&z| col(z) == SKIN)
            .count();
        assert!(orig >= 2);
        assert!(
            (top_skin as i64 - orig as i64).abs() <= 1,
            "{top_skin} vs {orig}"
        );
        // The top and bottom layers hold breast: it spans the thickness.
        let layer = |k: usize| {
            let n = c.dims[0] * c.dims[1];
            c.labels[k * n..(k + 1) * n].iter().any(|&l| l != 0)
        };
        assert!(layer(0) && layer(c.dims[2] - 1));
        // Finer output voxels: the same volume in mm^3.
        let f = compress(&v, dims, 0.5, 15.0, 0.25, 1.0).unwrap();
        let mm3 = |c: &Compressed, t| count(&c.labels, t) * c.voxel_mm.powi(3);
        assert!((mm3(&f, 29) / mm3(&c, 29) - 1.0).abs() < 0.03);
        // The affine map's in-plane stretch is sqrt(H / T) but for the
        // skin's share, which the interior's squeeze makes up.
        let affine = (c.height_mm / 15.0).sqrt();
        assert!(
            c.stretch > affine - 0.02 && c.stretch < 1.15 * affine,
            "{}",
            c.stretch
        );
    }

    /// With a contact fraction below 1 the breast is flattened against the
    /// paddle: every column at least that long spans the whole thickness,
    /// the breast fills more of its box than under the affine map, and it
    /// keeps its volume.
    #[test]
    fn a_contact_fraction_flattens_the_breast_against_the_paddle() {
        let (v, dims) = breast();
        let fill = |c: &Compressed| {
            // Tissue voxels over the footprint's columns times the thickness.
            let n = c.dims[0] * c.dims[1];
            let foot = (0..n)
                .filter(|&p| (0..c.dims[2]).any(|k| c.labels[p + n * k] != 0))
                .count();
            c.labels.iter().filter(|&&l| l != 0).count() as f64 / (foot * c.dims[2]) as f64
        };
        let affine = compress(&v, dims, 0.5, 15.0, 0.5, 1.0).unwrap();
        let flat = compress(&v, dims, 0.5, 15.0, 0.5, 0.5).unwrap();
        assert!(
            fill(&flat) > fill(&affine) + 0.1,
            "{} vs {}",
            fill(&flat),
            fill(&affine)
        );
        assert!(flat.stretch < affine.stretch);
        let count = |l: &[u8], t: u8| l.iter().filter(|&&x| x == t).count() as f64;
        // Every tissue under the skin keeps its volume (each column keeps
        // its own; nearest-neighbour resampling costs a few percent).
        for t in [1u8, 29] {
            let (a, b) = (count(&v, t), count(&flat.labels, t));
            assert!((b / a - 1.0).abs() < 0.04, "label {t}: {a} -> {b}");
        }
        // The centre column touches both plates.
        let n = flat.dims[0] * flat.dims[1];
        let centre = flat.dims[0] / 3 + flat.dims[0] * (flat.dims[1] / 2);
        assert!((0..flat.dims[2]).all(|k| flat.labels[centre + n * k] != 0));
        assert!(compress(&v, dims, 0.5, 15.0, 0.5, 0.0).is_err());
    }

    /// The written sidecar reads back through the product's external-phantom
    /// reader, with pc1's label map: the breast's thickness and its
    /// glandularity as the labels give it.
    #[test]
    fn the_sidecar_reads_back_with_pc1s_labels() {
        let (v, dims) = breast();
        let c = compress(&v, dims, 0.5, 15.0, 0.5, 0.5).unwrap();
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("b.raw"), &c.labels).unwrap();
        let toml = dir.path().join("b.toml");
        std::fs::write(&toml, sidecar(&c, "b.raw", "test")).unwrap();
        let vol = dbt_store::load_external_phantom(&toml).unwrap();
        assert!(
            (vol.thickness_mm() - 15.0).abs() < 0.51,
            "{}",
            vol.thickness_mm()
        );
        let g = vol.glandularity().unwrap();
        assert!(g > 0.0 && g < 1.0, "{g}");
        assert!(sidecar(&c, "b.raw", "test").contains("29 = \"fibroglandular\""));
    }

    /// Impossible requests are refused by name.
    #[test]
    fn bad_requests_are_named() {
        let (v, dims) = breast();
        assert!(matches!(
            compress(&v[1..], dims, 0.5, 15.0, 0.5, 1.0),
            Err(CompressError::Size { .. })
        ));
        let e = compress(&v, dims, 0.5, 45.0, 0.5, 1.0).unwrap_err();
        assert!(
            e.to_string()
                .contains("thicker than the uncompressed breast"),
            "{e}"
        );
        let e = compress(&v, dims, 0.5, f64::NAN, 0.5, 1.0).unwrap_err();
        assert!(e.to_string().starts_with("thickness_mm = NaN"), "{e}");
        let air = vec![0u8; v.len()];
        assert_eq!(
            compress(&air, dims, 0.5, 15.0, 0.5, 1.0),
            Err(CompressError::Empty)
        );
    }
}
