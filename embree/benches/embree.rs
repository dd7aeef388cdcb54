//! `embree` (feature `embree`): intersections per second on one tessellated surface, Embree
//! against the analytic intersection (Newton on the sag), on the same rays, one thread, warm
//! caches. lens2's first surface (R 33.6 mm) over a 15.9 mm disk at a 1e-4 mm chord bound
//! (~210k triangles, robust scene); 65,536 parallel rays at random points of a 15 mm disk,
//! traced in raster order (coherent, like a pupil grid) and in random order. Then one whole
//! cross-check case (`check_system`: meshes, scene builds, both Embree traces, the analytic
//! comparisons) of lens2 nominal with the default 32x32 grid at fields 0, 0.7, 1, meshing the
//! rays' footprints (the default) against whole disks.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use tolray::math::Vec3;
use tolray::trace::reference::intersect_local;
use tolray::Lens;
use tolray_embree::{
    check_rays, check_system, CheckOptions, Cover, Device, Frame, Mesh, Scene, SceneOptions,
};

fn bench(c: &mut Criterion) {
    let lens = Lens::load("lens2").unwrap();
    let sys = lens.compile();
    let row = &sys.rows[0];
    let mesh = Mesh::with_radius(row, 0, 15.9, 1e-4, Frame::Local).unwrap();
    let dev = Device::shared().unwrap();
    let scene = Scene::new(
        dev,
        &mesh.vertices,
        &mesh.triangles,
        SceneOptions::default(),
    )
    .unwrap();
    let mut seed = 0x2545f4914f6cdd1du64;
    let mut rnd = || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed >> 11) as f64 / (1u64 << 53) as f64
    };
    let d = Vec3::new(0.0, -0.25, 1.0).normalized();
    let random: Vec<(Vec3<f64>, Vec3<f64>)> = (0..65_536)
        .map(|_| {
            let r = 15.0 * rnd().sqrt();
            let a = std::f64::consts::TAU * rnd();
            let p = Vec3::new(r * a.cos(), r * a.sin(), 0.0);
            (p - d * (3.0 / d.z), d)
        })
        .collect();
    let mut raster = random.clone();
    raster.sort_by(|a, b| a.0.y.total_cmp(&b.0.y).then(a.0.x.total_cmp(&b.0.x)));
    let mut g = c.benchmark_group("embree/lens2-surface0");
    g.throughput(Throughput::Elements(random.len() as u64));
    g.sample_size(10);
    for (order, rays) in [("raster", &raster), ("random", &random)] {
        g.bench_function(format!("embree-intersect1/{order}"), |b| {
            b.iter(|| {
                let mut n = 0usize;
                for (o, d) in rays.iter() {
                    let org = [o.x as f32, o.y as f32, o.z as f32];
                    let dir = [d.x as f32, d.y as f32, d.z as f32];
                    n += scene.intersect(org, dir, 0.0, f32::INFINITY).is_some() as usize;
                }
                n
            })
        });
        g.bench_function(format!("analytic-newton/{order}"), |b| {
            b.iter(|| {
                rays.iter()
                    .filter(|(o, d)| intersect_local(row, *o, *d).is_some())
                    .count()
            })
        });
    }
    g.finish();

    let opts = CheckOptions::default();
    let rays = check_rays(&lens, &opts).unwrap();
    let mut g = c.benchmark_group("embree/check-case/lens2");
    g.sample_size(10);
    for cover in [Cover::Footprint, Cover::Disk] {
        let o = CheckOptions {
            cover,
            ..opts.clone()
        };
        g.bench_function(format!("{cover:?}").to_lowercase(), |b| {
            b.iter(|| check_system(dev, &sys, &rays, &o).unwrap().timing.triangles)
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
