//! Labels of `sample_uniform(.., N, 12)` poses as text, one line per pose: collides, self,
//! scene, n_pairs, the bits of min_distance (with DISTANCE = 1) and the colliding pairs; or,
//! with DISTANCE = fk, the bits of forward kinematics. Two builds label byte-identically when
//! their outputs are equal:
//!
//! ```text
//! cargo build --release --example dump_labels
//! target/release/examples/dump_labels benches/data/panda_blocks.json 100000 0 > labels.txt
//! ```

use std::io::Write;

use profrobot::collision::collide::{label_batch, label_pose, LabelBatch, LabelOptions, Scratch};
use profrobot::{sample_uniform, ModelDesc, RobotModel};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let [_, path, n, distance] = args.as_slice() else {
        eprintln!("usage: dump_labels SCENE.json N DISTANCE(0|1|fk)");
        std::process::exit(2);
    };
    let text = std::fs::read_to_string(path).expect("readable scene JSON");
    let desc: ModelDesc = serde_json::from_str(&text).expect("valid scene JSON");
    let model = RobotModel::new(desc).expect("valid scene");
    let n: usize = n.parse().expect("N poses");
    let opts = LabelOptions { pairs: true, distance: distance == "1" };
    let poses = sample_uniform(&model.sampling_ranges().unwrap(), n, 12).unwrap();
    if distance == "fk" {
        // Forward kinematics instead: the bits of every body's position and quaternion.
        let (xpos, xquat) = profrobot::forward_kinematics(&model, &poses).expect("finite poses");
        let mut out = std::io::BufWriter::new(std::io::stdout().lock());
        for v in xpos.iter().chain(&xquat) {
            writeln!(out, "{:x}", v.to_bits()).expect("stdout");
        }
        return;
    }
    // (as the Python entry points label: skipping the pairs proven apart)
    profrobot::planning::motion::prove_apart(&model);
    let mut s = Scratch::new(&model);
    let mut out = std::io::BufWriter::new(std::io::stdout().lock());
    // (through the batch, as users label: poses placed four at a time; `ONE=1`: one at a time)
    let batch = if std::env::var_os("ONE").is_some() {
        let mut batch = LabelBatch::default();
        let mut hits = Vec::new();
        for (i, q) in poses.chunks_exact(model.njoint()).enumerate() {
            hits.clear();
            batch.labels.push(label_pose(&model, q, &mut s, opts, &mut hits).expect("a decidable pose"));
            batch.colliding_pairs.extend(hits.iter().map(|&k| [i as u32, k]));
        }
        batch
    } else {
        label_batch(&model, &poses, opts).expect("decidable poses")
    };
    let mut pairs = batch.colliding_pairs.iter().peekable();
    for (i, l) in batch.labels.iter().enumerate() {
        let mut hits = Vec::new();
        while let Some(&[_, k]) = pairs.next_if(|p| p[0] == i as u32) {
            hits.push(k);
        }
        let bits = l.min_distance.to_bits();
        let (c, sc, ss) = (l.collides() as u8, l.self_collides as u8, l.scene_collides as u8);
        writeln!(out, "{c} {sc} {ss} {} {bits:x} {hits:?}", l.n_pairs).expect("stdout");
    }
}
