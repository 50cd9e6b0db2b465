//! Labelling throughput (poses/s) on the bundled scenes, exported by
//! `python benches/export_scene.py` into `benches/data/*.json`.
//!
//! `cargo bench` prints poses/s for one thread and for all threads; MuJoCo's side-by-side
//! ratio is in `benches/labelling.py` (it needs Python).

use std::path::Path;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use profrobot::{label_batch, sample_uniform, with_threads, LabelOptions, ModelDesc, RobotModel};

const N: usize = 20_000;

fn load(scene: &str) -> RobotModel {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/data").join(format!("{scene}.json"));
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let desc: ModelDesc = serde_json::from_str(&text).expect("valid scene JSON");
    RobotModel::new(desc).expect("valid scene")
}

fn bench(c: &mut Criterion) {
    let cores = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
    for scene in ["panda_blocks", "ur5e_wall_box", "shadow_hand"] {
        let model = load(scene);
        let poses = sample_uniform(&model.sampling_ranges().unwrap(), N, 0).unwrap();
        let mut group = c.benchmark_group(format!("label/{scene}"));
        group.throughput(Throughput::Elements(N as u64));
        group.sample_size(10);
        for threads in [1, cores] {
            group.bench_function(format!("{threads}_threads"), |b| {
                b.iter(|| with_threads(Some(threads), || label_batch(&model, &poses, LabelOptions::default()).unwrap()).unwrap())
            });
        }
        group.finish();
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
