//! ONNX export, the protobuf written directly (ONNX IR 8, opset 13):
//!
//! - a policy's deterministic action, so the lab can run it from Python (e.g. onnxruntime) on
//!   the robot PC: input `obs` (float32, batch x obs_dim), output `turn` (float32, batch x 1)
//!   = clip(mean, -1, 1) · π in radians: exactly the action fishprobe sends;
//! - M_ConvNet in fishprobe's fish-model contract (`docs/onnx-models.md`): input `view`
//!   (float32, batch x 3 x bins), output `logits` (float32, batch x cells), the grid in the
//!   file's `metadata_props`. The circular padding of the convolution is written as two
//!   `Slice`s and a `Concat` (ONNX's `Pad` has no wrap mode before opset 19).

use crate::error::LearnError;
use crate::policy::GaussianPolicy;
use fishprobe_nn::Activation;
use std::f32::consts::PI;

/// A protobuf message under construction.
#[derive(Default)]
struct Msg(Vec<u8>);

impl Msg {
    fn varint(&mut self, mut v: u64) {
        while v >= 0x80 {
            self.0.push((v as u8) | 0x80);
            v >>= 7;
        }
        self.0.push(v as u8);
    }
    fn key(&mut self, field: u64, wire: u64) {
        self.varint((field << 3) | wire);
    }
    fn int(&mut self, field: u64, v: i64) -> &mut Self {
        self.key(field, 0);
        self.varint(v as u64);
        self
    }
    fn bytes(&mut self, field: u64, b: &[u8]) -> &mut Self {
        self.key(field, 2);
        self.varint(b.len() as u64);
        self.0.extend_from_slice(b);
        self
    }
    fn string(&mut self, field: u64, s: &str) -> &mut Self {
        self.bytes(field, s.as_bytes())
    }
    fn msg(&mut self, field: u64, m: &Msg) -> &mut Self {
        self.bytes(field, &m.0)
    }
    fn float(&mut self, field: u64, v: f32) -> &mut Self {
        self.key(field, 5);
        self.0.extend_from_slice(&v.to_le_bytes());
        self
    }
}

const FLOAT: i64 = 1;
const INT64: i64 = 7;

fn int_tensor(name: &str, data: &[i64]) -> Msg {
    let mut t = Msg::default();
    t.int(1, data.len() as i64);
    t.int(2, INT64).string(8, name);
    let raw: Vec<u8> = data.iter().flat_map(|v| v.to_le_bytes()).collect();
    t.bytes(9, &raw);
    t
}

/// A value's type: float32 of shape `[batch, dims...]`.
fn value_info_dims(name: &str, dims: &[usize]) -> Msg {
    let mut shape = Msg::default();
    let mut batch = Msg::default();
    batch.string(2, "batch");
    shape.msg(1, &batch);
    for &d in dims {
        let mut dim = Msg::default();
        dim.int(1, d as i64);
        shape.msg(1, &dim);
    }
    let mut tensor_type = Msg::default();
    tensor_type.int(1, FLOAT).msg(2, &shape);
    let mut ty = Msg::default();
    ty.msg(1, &tensor_type);
    let mut vi = Msg::default();
    vi.string(1, name).msg(2, &ty);
    vi
}

/// A node with one integer attribute.
fn node_int(op: &str, inputs: &[&str], output: &str, attr: (&str, i64)) -> Msg {
    let mut n = node(op, inputs, output, None);
    let mut a = Msg::default();
    a.string(1, attr.0).int(3, attr.1).int(20, 2);
    n.msg(5, &a);
    n
}

fn tensor(name: &str, dims: &[usize], data: &[f32]) -> Msg {
    let mut t = Msg::default();
    for &d in dims {
        t.int(1, d as i64);
    }
    t.int(2, FLOAT).string(8, name);
    let raw: Vec<u8> = data.iter().flat_map(|v| v.to_le_bytes()).collect();
    t.bytes(9, &raw);
    t
}

fn node(op: &str, inputs: &[&str], output: &str, attr: Option<(&str, f32)>) -> Msg {
    let mut n = Msg::default();
    for i in inputs {
        n.string(1, i);
    }
    n.string(2, output).string(3, output).string(4, op);
    if let Some((name, v)) = attr {
        let mut a = Msg::default();
        a.string(1, name).float(2, v).int(20, 1);
        n.msg(5, &a);
    }
    n
}

/// The ONNX model bytes of a policy's deterministic action.
pub fn policy_to_onnx(policy: &GaussianPolicy) -> Result<Vec<u8>, LearnError> {
    let net = &policy.pi;
    let sizes = &net.spec().sizes;
    let layers = sizes.len() - 1;
    let mut graph = Msg::default();
    let mut inits = Vec::new();
    let mut x = "obs".to_string();
    for l in 0..layers {
        let (w, b) = net.layer(l);
        let (inp, out) = (sizes[l], sizes[l + 1]);
        // The last layer outputs (mean, log_std): export the mean column only.
        let (w, b, out) = if l + 1 == layers {
            (
                w.chunks_exact(out).map(|row| row[0]).collect::<Vec<f32>>(),
                vec![b[0]],
                1,
            )
        } else {
            (w.to_vec(), b.to_vec(), out)
        };
        inits.push(tensor(&format!("W{l}"), &[inp, out], &w));
        inits.push(tensor(&format!("b{l}"), &[out], &b));
        graph.msg(
            1,
            &node("MatMul", &[&x, &format!("W{l}")], &format!("mm{l}"), None),
        );
        graph.msg(
            1,
            &node(
                "Add",
                &[&format!("mm{l}"), &format!("b{l}")],
                &format!("z{l}"),
                None,
            ),
        );
        x = format!("z{l}");
        if l + 1 < layers {
            let (op, attr) = match net.spec().hidden {
                Activation::Tanh => ("Tanh", None),
                Activation::LeakyRelu(a) => ("LeakyRelu", Some(("alpha", a))),
            };
            graph.msg(1, &node(op, &[&x], &format!("h{l}"), attr));
            x = format!("h{l}");
        }
    }
    inits.push(tensor("lo", &[], &[-1.0]));
    inits.push(tensor("hi", &[], &[1.0]));
    inits.push(tensor("scale", &[1], &[PI]));
    graph.msg(1, &node("Clip", &[&x, "lo", "hi"], "clipped", None));
    graph.msg(1, &node("Mul", &["clipped", "scale"], "turn", None));
    graph.string(2, "fishprobe_policy");
    for t in &inits {
        graph.msg(5, t);
    }
    graph.msg(11, &value_info_dims("obs", &[policy.obs_dim()]));
    graph.msg(12, &value_info_dims("turn", &[1]));
    Ok(model_proto(&graph, &[]))
}

/// The ONNX model bytes of M_ConvNet in fishprobe's fish-model contract.
pub fn convnet_to_onnx(net: &fishprobe_models::ConvNet) -> Result<Vec<u8>, LearnError> {
    let a = &net.arch;
    let (bins, half) = (a.bins, a.kernel / 2);
    let alpha = Some(("alpha", a.leaky_slope));
    let mut graph = Msg::default();
    let mut inits = vec![
        int_tensor("wrap_lo_start", &[(bins - half) as i64]),
        int_tensor("wrap_lo_end", &[bins as i64]),
        int_tensor("wrap_hi_start", &[0]),
        int_tensor("wrap_hi_end", &[half as i64]),
        int_tensor("bin_axis", &[2]),
    ];
    // Circular padding: the last `half` bins before the first, the first `half` after the last.
    graph.msg(
        1,
        &node(
            "Slice",
            &["view", "wrap_lo_start", "wrap_lo_end", "bin_axis"],
            "wrap_lo",
            None,
        ),
    );
    graph.msg(
        1,
        &node(
            "Slice",
            &["view", "wrap_hi_start", "wrap_hi_end", "bin_axis"],
            "wrap_hi",
            None,
        ),
    );
    graph.msg(
        1,
        &node_int(
            "Concat",
            &["wrap_lo", "view", "wrap_hi"],
            "padded",
            ("axis", 2),
        ),
    );
    let conv = &net.conv;
    let nw = conv.c_out * conv.c_in * conv.k;
    inits.push(tensor(
        "conv_w",
        &[conv.c_out, conv.c_in, conv.k],
        &conv.params[..nw],
    ));
    inits.push(tensor(
        "conv_b",
        &[conv.c_out],
        &conv.params[nw..nw + conv.c_out],
    ));
    graph.msg(
        1,
        &node("Conv", &["padded", "conv_w", "conv_b"], "conv", None),
    );
    graph.msg(1, &node("LeakyRelu", &["conv"], "conv_act", alpha));
    // batch x c_out x bins, flattened channel-major as fishprobe's dense layers read it.
    graph.msg(
        1,
        &node_int("Flatten", &["conv_act"], "features", ("axis", 1)),
    );
    let sizes = &net.mlp.spec().sizes;
    let layers = sizes.len() - 1;
    let mut x = "features".to_string();
    for l in 0..layers {
        let (w, b) = net.mlp.layer(l);
        inits.push(tensor(&format!("W{l}"), &[sizes[l], sizes[l + 1]], w));
        inits.push(tensor(&format!("b{l}"), &[sizes[l + 1]], b));
        graph.msg(
            1,
            &node("MatMul", &[&x, &format!("W{l}")], &format!("mm{l}"), None),
        );
        let z = if l + 1 == layers {
            "logits".to_string()
        } else {
            format!("z{l}")
        };
        graph.msg(
            1,
            &node("Add", &[&format!("mm{l}"), &format!("b{l}")], &z, None),
        );
        x = z;
        if l + 1 < layers {
            graph.msg(1, &node("LeakyRelu", &[&x], &format!("h{l}"), alpha));
            x = format!("h{l}");
        }
    }
    graph.string(2, "fishprobe_convnet");
    for t in &inits {
        graph.msg(5, t);
    }
    graph.msg(
        11,
        &value_info_dims("view", &[fishprobe_models::convnet::CHANNELS, bins]),
    );
    graph.msg(12, &value_info_dims("logits", &[a.cells()]));
    // The grid, so the file says what its logits mean.
    let grid = [
        ("v_max_cm_s", a.v_max_cm_s.to_string()),
        ("v_bins", a.v_bins.to_string()),
        ("omega_max_rad_s", a.w_max_rad_s.to_string()),
        ("omega_bins", a.w_bins.to_string()),
    ];
    Ok(model_proto(&graph, &grid))
}

/// The ModelProto around `graph` (ONNX IR 8, opset 13, producer fishprobe and its version),
/// with `metadata_props`.
fn model_proto(graph: &Msg, metadata: &[(&str, String)]) -> Vec<u8> {
    let mut opset = Msg::default();
    opset.string(1, "").int(2, 13);
    let mut model = Msg::default();
    model
        .int(1, 8)
        .string(2, "fishprobe")
        .string(3, env!("CARGO_PKG_VERSION"))
        .msg(7, graph)
        .msg(8, &opset);
    for (k, v) in metadata {
        let mut e = Msg::default();
        e.string(1, k).string(2, v);
        model.msg(14, &e);
    }
    model.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn varints_and_keys_follow_protobuf() {
        let mut m = Msg::default();
        m.varint(300);
        assert_eq!(m.0, vec![0xAC, 0x02]);
        let mut m = Msg::default();
        m.int(1, 8);
        assert_eq!(m.0, vec![0x08, 0x08]);
        let mut m = Msg::default();
        m.string(2, "ab");
        assert_eq!(m.0, vec![0x12, 0x02, b'a', b'b']);
    }
}
