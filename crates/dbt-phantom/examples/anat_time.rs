use dbt_geometry::Geometry;
use dbt_phantom::{generate, generate_anatomical, AnatomicalPopulation, Population};
fn main() {
    let g = Geometry::builtin("paper-104").unwrap().binned(4).unwrap();
    let pop = AnatomicalPopulation::for_geometry(&g);
    let old = Population::for_geometry(&g);
    for i in 0..4u64 {
        let s = pop.draw(5, i);
        let t = std::time::Instant::now();
        let v = generate_anatomical(&s).unwrap();
        let dt = t.elapsed().as_secs_f64();
        let t2 = std::time::Instant::now();
        let o = generate(&old.draw(5, i)).unwrap();
        let dt2 = t2.elapsed().as_secs_f64();
        println!("T {:.1} L {:.1} W {:.1} g {:.3} -> {:.3} dims {:?} {:.2}s (old {:.2}s dims {:?}) counts {:?}",
            s.thickness_mm, s.chest_to_nipple_mm, s.width_mm, s.glandularity, v.glandularity().unwrap(), v.dims(), dt, dt2, o.dims(), v.counts());
    }
}
