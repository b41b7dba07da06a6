//! Every layer's analytic gradient against central finite differences.

#![allow(clippy::unwrap_used)]
// a failure is a test failure
// Perturbing parameter i while reading gradient i is clearest as an index loop.
#![allow(clippy::needless_range_loop)]

use fishprobe_nn::store::{load, save, Tensors};
use fishprobe_nn::{Activation, Conv1d, Mlp, MlpSpec, MlpWorkspace};
use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

/// Compares analytic and numeric gradients: |a - n| <= 2e-3 + 2e-2 |n|. (f32 arithmetic and a
/// fast tanh whose derivative is taken as 1 - y² bound the agreement.)
fn close(a: f32, n: f32) -> bool {
    (a - n).abs() <= 2e-3 + 2e-2 * n.abs()
}

/// Checks every parameter and input gradient of an MLP with these layer sizes, for `batch`
/// rows (up to 4 rows take the few-rows product, more take `sgemm`; outputs up to 4 wide take
/// the narrow output layer, wider ones `sgemm`).
fn check_mlp(hidden: Activation, sizes: &[usize], batch: usize, sparse_input: bool) {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(1);
    let (n_in, n_out) = (sizes[0], sizes[sizes.len() - 1]);
    let spec = MlpSpec {
        sizes: sizes.to_vec(),
        hidden,
    };
    let mut net = Mlp::new(spec, 1.0, &mut rng);
    let x: Vec<f32> = (0..batch * n_in)
        .map(|i| {
            let v = rng.random_range(-1.0..1.0);
            // A sparse input (two entries in three zero) takes the first layer's sparse path.
            if sparse_input && i % 3 != 0 {
                0.0
            } else {
                v
            }
        })
        .collect();
    let c: Vec<f32> = (0..batch * n_out)
        .map(|_| rng.random_range(-1.0..1.0))
        .collect();
    let mut ws = MlpWorkspace::default();
    // loss = Σ c · y
    let loss = |net: &Mlp, x: &[f32], ws: &mut MlpWorkspace| -> f32 {
        net.forward(x, batch, ws)
            .iter()
            .zip(&c)
            .map(|(y, c)| y * c)
            .sum()
    };
    loss(&net, &x, &mut ws);
    let mut grads = vec![0.0; net.num_params()];
    let mut dx = vec![0.0; x.len()];
    net.backward(&x, batch, &c, &mut ws, &mut grads, Some(&mut dx));
    // Leaky-ReLU is piecewise linear: where a step straddles a kink the central difference
    // averages two slopes, and the analytic gradient must equal one of the one-sided ones.
    let kinked = matches!(hidden, Activation::LeakyRelu(_));
    let h = 1e-2;
    let base = loss(&net, &x, &mut ws);
    for i in 0..net.num_params() {
        let orig = net.params()[i];
        net.params_mut()[i] = orig + h;
        let up = loss(&net, &x, &mut ws);
        net.params_mut()[i] = orig - h;
        let down = loss(&net, &x, &mut ws);
        net.params_mut()[i] = orig;
        let num = (up - down) / (2.0 * h);
        let one_sided =
            kinked && (close(grads[i], (up - base) / h) || close(grads[i], (base - down) / h));
        assert!(
            close(grads[i], num) || one_sided,
            "{hidden:?} param {i}: analytic {} numeric {num}",
            grads[i]
        );
    }
    for i in 0..x.len() {
        let mut xp = x.clone();
        xp[i] += h;
        let up = loss(&net, &xp, &mut ws);
        xp[i] -= 2.0 * h;
        let down = loss(&net, &xp, &mut ws);
        let num = (up - down) / (2.0 * h);
        let one_sided =
            kinked && (close(dx[i], (up - base) / h) || close(dx[i], (base - down) / h));
        assert!(
            close(dx[i], num) || one_sided,
            "{hidden:?} input {i}: analytic {} numeric {num}",
            dx[i]
        );
    }
}

#[test]
fn dense_layers_with_tanh() {
    check_mlp(Activation::Tanh, &[5, 7, 11, 3], 4, false);
    check_mlp(Activation::Tanh, &[5, 7, 11, 3], 9, false);
    check_mlp(Activation::Tanh, &[5, 7, 11, 9], 9, false);
}

#[test]
fn dense_layers_with_leaky_relu() {
    check_mlp(Activation::LeakyRelu(0.01), &[5, 7, 6, 3], 4, false);
    check_mlp(Activation::LeakyRelu(0.01), &[5, 7, 11, 2], 9, false);
}

#[test]
fn a_sparse_input_takes_the_sparse_first_layer() {
    check_mlp(Activation::Tanh, &[13, 40, 11, 3], 9, true);
    check_mlp(Activation::Tanh, &[13, 2], 9, true);
}

#[test]
fn a_single_narrow_layer_passes_the_input_gradient() {
    check_mlp(Activation::Tanh, &[13, 2], 6, false);
    check_mlp(Activation::Tanh, &[13, 6], 6, false);
}

#[test]
fn circular_convolution() {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(2);
    let (batch, c_in, c_out, k, len) = (2, 3, 4, 5, 9);
    let mut conv = Conv1d::new(c_in, c_out, k, &mut rng);
    conv.params
        .iter_mut()
        .skip(c_out * c_in * k)
        .for_each(|b| *b = rng.random_range(-0.5..0.5));
    let x: Vec<f32> = (0..batch * c_in * len)
        .map(|_| rng.random_range(-1.0..1.0))
        .collect();
    let c: Vec<f32> = (0..batch * c_out * len)
        .map(|_| rng.random_range(-1.0..1.0))
        .collect();
    let mut out = vec![0.0; c.len()];
    let loss = |conv: &Conv1d, x: &[f32], out: &mut [f32]| -> f32 {
        conv.forward(x, batch, len, out);
        out.iter().zip(&c).map(|(y, c)| y * c).sum()
    };
    let mut grads = vec![0.0; conv.params.len()];
    let mut dx = vec![0.0; x.len()];
    conv.backward(&x, batch, len, &c, &mut grads, Some(&mut dx));
    let h = 1e-2;
    for i in 0..conv.params.len() {
        let orig = conv.params[i];
        conv.params[i] = orig + h;
        let up = loss(&conv, &x, &mut out);
        conv.params[i] = orig - h;
        let down = loss(&conv, &x, &mut out);
        conv.params[i] = orig;
        let num = (up - down) / (2.0 * h);
        assert!(
            close(grads[i], num),
            "param {i}: analytic {} numeric {num}",
            grads[i]
        );
    }
    for i in 0..x.len() {
        let mut xp = x.clone();
        xp[i] += h;
        let up = loss(&conv, &xp, &mut out);
        xp[i] -= 2.0 * h;
        let down = loss(&conv, &xp, &mut out);
        assert!(close(dx[i], (up - down) / (2.0 * h)), "input {i}");
    }
    // Circularity: an impulse at the last bin reaches the first output bin.
    let mut one = Conv1d {
        c_in: 1,
        c_out: 1,
        k: 3,
        params: vec![0.0, 0.0, 1.0, 0.0],
    };
    let mut imp = vec![0.0; 5];
    imp[0] = 1.0;
    let mut y = vec![0.0; 5];
    one.forward(&imp, 1, 5, &mut y);
    // Tap j = 2 reads in[t + 1]: output t = 4 sees in[0].
    assert_eq!(y, vec![0.0, 0.0, 0.0, 0.0, 1.0]);
    one.params[0] = 1.0;
    one.params[2] = 0.0;
    one.forward(&imp, 1, 5, &mut y);
    assert_eq!(y, vec![0.0, 1.0, 0.0, 0.0, 0.0]);
}

#[test]
fn weights_round_trip_and_damage_is_an_error() {
    let dir = std::env::temp_dir().join(format!("fishprobe-nn-{}", std::process::id()));
    let p = dir.join("w.safetensors");
    let mut t = Tensors::new();
    t.insert("a".into(), (vec![2, 3], vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0]));
    t.insert("b".into(), (vec![1], vec![-0.5]));
    save(&p, &t, &serde_json::json!({"format": "test", "version": 1})).unwrap();
    let (back, meta) = load(&p).unwrap();
    assert_eq!(back, t);
    assert_eq!(meta["version"], 1);
    let mut bytes = std::fs::read(&p).unwrap();
    bytes.truncate(bytes.len() - 3);
    std::fs::write(&p, &bytes).unwrap();
    let e = load(&p).unwrap_err().to_string();
    assert!(e.contains("w.safetensors"), "{e}");
    std::fs::remove_file(fishprobe_nn::store::sidecar_path(&p)).unwrap();
    assert!(load(&dir.join("absent.safetensors")).is_err());
    // Removed when the test passes, left for a look when it fails.
    std::fs::remove_dir_all(&dir).unwrap();
}
