//! AAPM TG-195 case 3 (mammography geometry), as described in
//! `shared/reference/tg195-case3.md`. z = 0 is the detector plane; x runs from
//! the chest wall (x = 0) toward the nipple; y along the chest wall.

use crate::material::Material;
use crate::scene::{HomogeneousBox, Scene, VoxelGrid};
use crate::spectrum::Spectrum;
use crate::tables::elements;
use crate::transport::PointSource;
use crate::DoseError;
use dbt_materials::{glandular_adipose_mix, Tissue, AIR, PMMA, WATER};

/// Material codes of the case.
pub const AIR_M: u8 = 0;
/// 20 % glandular / 80 % adipose by weight.
pub const BREAST_M: u8 = 1;
/// Skin.
pub const SKIN_M: u8 = 2;
/// PMMA compression plates.
pub const PMMA_M: u8 = 3;
/// The body.
pub const WATER_M: u8 = 4;

/// VOI centres (mm); each VOI is 20 x 20 x 10 mm (x, y, z).
pub const VOI_CENTRES: [[f64; 3]; 7] = [
    [50.0, -50.0, 40.0],
    [20.0, 0.0, 40.0],
    [50.0, 0.0, 40.0],
    [80.0, 0.0, 40.0],
    [50.0, 50.0, 40.0],
    [50.0, 0.0, 25.0],
    [50.0, 0.0, 55.0],
];

/// Published reference at 16.8 keV, 0 degrees: total, eV per photon.
pub const REF_TOTAL_EV: f64 = 4697.3;
/// Published reference VOIs 1..7, eV per photon.
pub const REF_VOI_EV: [f64; 7] = [17.692, 18.070, 17.865, 17.262, 17.768, 5.417, 56.017];

/// The case-3 scene with a voxel grid of side `voxel_mm` (must divide 1 mm
/// boundaries: 0.5, 1, ...).
pub fn scene(voxel_mm: f64) -> Result<Scene, DoseError> {
    let els = elements()?;
    // 20 % glandular / 80 % adipose by weight; TG-195 specifies 0.952 g/cm3.
    let (mix, _) = glandular_adipose_mix(0.2);
    let gland = Material::tissue(Tissue::Fibroglandular, els)?;
    let materials = vec![
        Material::medium(&AIR, els)?,
        Material::new("breast 20/80", 0.952, &mix, els)?.glandular_share(0.2, &gland),
        Material::tissue(Tissue::Skin, els)?,
        Material::medium(&PMMA, els)?,
        Material::medium(&WATER, els)?,
    ];
    let origin = [0.0, -130.0, 13.0];
    let ext = [140.0, 260.0, 54.0];
    let dims = ext.map(|e| (e / voxel_mm).round() as usize);
    let mut grid = VoxelGrid {
        origin,
        voxel_mm,
        dims,
        material: vec![AIR_M; dims.iter().product()],
        tally: vec![0; dims.iter().product()],
    };
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                let [x, y, z] = grid.centre(i, j, k);
                let r = x.hypot(y);
                let idx = (k * dims[1] + j) * dims[0] + i;
                let m = if !(15.0..=65.0).contains(&z) {
                    PMMA_M
                } else if r < 100.0 {
                    if r < 98.0 && (17.0..=63.0).contains(&z) {
                        BREAST_M
                    } else {
                        SKIN_M
                    }
                } else {
                    AIR_M
                };
                grid.material[idx] = m;
                if m == BREAST_M {
                    for (v, c) in VOI_CENTRES.iter().enumerate() {
                        if (x - c[0]).abs() < 10.0
                            && (y - c[1]).abs() < 10.0
                            && (z - c[2]).abs() < 5.0
                        {
                            grid.tally[idx] = v as u8 + 1;
                        }
                    }
                }
            }
        }
    }
    let scene = Scene {
        materials,
        grid,
        boxes: vec![HomogeneousBox {
            min: [-170.0, -150.0, -110.0],
            max: [0.0, 150.0, 190.0],
            material: WATER_M,
        }],
        world_material: AIR_M,
        world_min: [-1000.0, -1000.0, -1000.0],
        world_max: [1000.0, 1000.0, 1000.0],
        n_tallies: 7,
        summary: Default::default(),
    };
    scene.validate()?;
    Ok(scene)
}

/// The case-3 source: isotropic point at (0, 0, 660) rotated by `angle_deg`
/// about the x axis through the origin, collimated to x in [0, 140], y in
/// [-130, 130] at z = 0 (the detector, which does not move).
pub fn source(angle_deg: f64, spectrum: Spectrum) -> PointSource {
    let a = angle_deg.to_radians();
    PointSource::rect_z(
        [0.0, 660.0 * a.sin(), 660.0 * a.cos()],
        [0.0, 140.0],
        [-130.0, 130.0],
        0.0,
        spectrum,
    )
}
