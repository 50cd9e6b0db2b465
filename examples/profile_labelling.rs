//! Single-threaded labelling (the batch functions in a pool of one thread) for instruction counts (`valgrind --tool=callgrind`), free of
//! thread-pool noise: `cargo build --release --example profile_labelling`, then
//!
//! ```text
//! valgrind --tool=callgrind --toggle-collect='*profile_labelling::run*' \
//!     target/release/examples/profile_labelling benches/data/panda_blocks.json label 20000
//! ```
//!
//! Modes: `label` (the four labels), `collides` (the booleans-only fast path), `distance`
//! (labels and the minimum signed distance). Poses are `sample_uniform(.., n, 0)`. Prints the
//! number of colliding poses, so that two builds can be checked to agree. With `TIME=R` set, also
//! the best of R timed runs in microseconds a pose (one thread; a quiet machine, load average
//! beside it).

use profrobot::collision::collide::{label_batch, LabelOptions};
use profrobot::collision::fastpath::{collides_batch, likely_pairs};
use profrobot::{sample_uniform, ModelDesc, RobotModel};

#[inline(never)]
fn run(model: &RobotModel, poses: &[f64], mode: &str) -> usize {
    // (the batches users call, on this thread: poses placed four at a time)
    let opts = LabelOptions { pairs: false, distance: mode == "distance" };
    match mode {
        "collides" => collides_batch(model, poses).expect("decidable poses").into_iter().filter(|&c| c).count(),
        _ => label_batch(model, poses, opts).expect("decidable poses").labels.iter().filter(|l| l.collides()).count(),
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let [_, path, mode, n] = args.as_slice() else {
        eprintln!("usage: profile_labelling SCENE.json label|collides|distance N");
        std::process::exit(2);
    };
    let text = std::fs::read_to_string(path).expect("readable scene JSON");
    let desc: ModelDesc = serde_json::from_str(&text).expect("valid scene JSON");
    let model = RobotModel::new(desc).expect("valid scene");
    let n: usize = n.parse().expect("N poses");
    let poses = sample_uniform(&model.sampling_ranges().unwrap(), n, 0).unwrap();
    likely_pairs(&model); // computed once per model, outside the count
    if std::env::var_os("NO_APART").is_none() {
        let t = std::time::Instant::now();
        profrobot::planning::motion::prove_apart(&model); // likewise
        eprintln!("prove_apart: {:.3} s", t.elapsed().as_secs_f64());
    }
    // One thread: the batches run inline in a pool of one.
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().expect("a pool of one");
    let run = |model: &RobotModel, poses: &[f64], mode: &str| pool.install(|| run(model, poses, mode));
    let hits = run(&model, &poses, mode);
    println!("{hits} of {n} collide");
    if let Some(reps) = std::env::var("TIME").ok().and_then(|r| r.parse::<usize>().ok()) {
        let best = (0..reps)
            .map(|_| {
                let t = std::time::Instant::now();
                std::hint::black_box(run(&model, &poses, mode));
                t.elapsed().as_secs_f64()
            })
            .fold(f64::INFINITY, f64::min);
        println!("{:.3} us a pose (best of {reps})", best / n as f64 * 1e6);
    }
}
