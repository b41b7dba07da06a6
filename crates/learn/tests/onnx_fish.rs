//! M_ConvNet exported in fishprobe's fish-model contract and loaded back as an ONNX model
//! gives the native network's logits on real views (the bar: max |Δ| ≤ 1e-4 over 10,000
//! views of the shared guppy-pair recordings), and the same fish in the simulator.

#![allow(clippy::unwrap_used)] // a failure is a test failure

use fishprobe_learn::bc::{load_pairs, CloneConfig};
use fishprobe_models::convnet::ConvNetWorkspace;
use fishprobe_models::{ConvNet, OnnxFish, OnnxParams};

#[test]
fn exported_convnet_gives_the_native_logits_on_10000_real_views() {
    let Some(data) = fishprobe_io::shared_data_dir() else {
        eprintln!("skipping: FISHPROBE_DATA is not set and ../shared/data is absent");
        return;
    };
    let net = ConvNet::shipped().unwrap();
    let dir = std::env::temp_dir().join(format!("fishprobe-onnx-fish-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("convnet.onnx");
    std::fs::write(&file, fishprobe_learn::onnx::convnet_to_onnx(&net).unwrap()).unwrap();
    let fish = OnnxFish::load(&OnnxParams::for_file(file.to_str().unwrap())).unwrap();
    assert_eq!(
        fish.arch(),
        &net.arch,
        "the grid read back from metadata_props"
    );

    let pairs = data.join("guppy-pairs/legacy/validation");
    assert!(pairs.is_dir(), "{} missing", pairs.display());
    let d = load_pairs(&[pairs], &net.arch, &CloneConfig::default()).unwrap();
    let (len, cells) = (net.arch.view_len(), net.arch.cells());
    let n = d.len().min(10_000);
    assert!(n == 10_000, "only {n} views");
    let batch = 500;
    let mut ws = ConvNetWorkspace::default();
    let mut got = vec![0.0f32; batch * cells];
    let mut worst = 0.0f32;
    for start in (0..n).step_by(batch) {
        let x = &d.x[start * len..(start + batch) * len];
        let native = net.forward(x, batch, &mut ws).to_vec();
        fish.logits(x, batch, &mut got).unwrap();
        for (a, b) in native.iter().zip(&got) {
            worst = worst.max((a - b).abs());
        }
    }
    println!("max |logit difference| over {n} views: {worst:e}");
    assert!(worst <= 1e-4, "max |logit difference| {worst}");
    std::fs::remove_dir_all(&dir).ok();
}
