//! Reading a block's weights out of its ONNX file for the fast path
//! (`dbt-conv`): the graph must be exactly the block `export.py` writes, in
//! fp32 or in the static QDQ int8 form; anything else is refused with the
//! node that did not fit, so the fast path never runs a graph it does not
//! reproduce (tract, the reference executor, runs any graph).
//!
//! fp32: `out = Add(state, Conv3(PRelu2(Conv2(PRelu1(Conv1(Concat(state, aux)))))))`.
//! int8: the same with int8 weights per output channel and int32 biases
//! behind `DequantizeLinear`, and `DequantizeLinear(QuantizeLinear(.))` on
//! every convolution's input, and optionally on every other activation:
//! export.py's three `--int8-form`s. `plain` (onnxruntime's graph) quantizes
//! them all, the residual too: `out = DQ(Q(Add(DQ(Q(state)), c3)))`;
//! `float-residual` all but the residual, `out = Add(state, DQ(Q(conv3)))`;
//! `conv-inputs` only the convolutions' inputs, with the concatenation
//! multiplied by per-channel factors first:
//! `conv1(DQ(Q(Mul(Concat(state, aux), k))))`, `out = Add(state, conv3)`.

use crate::DbtorError;
use dbt_conv::{BlockWeights, Conv3x3, Int8BlockWeights, Int8Conv, QuantParams};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use tract_onnx::pb;
use tract_onnx::prelude::*;

struct Graph<'a> {
    path: PathBuf,
    producers: HashMap<&'a str, &'a pb::NodeProto>,
    inits: HashMap<&'a str, &'a pb::TensorProto>,
    inputs: Vec<&'a str>,
    output: &'a str,
    onnx: tract_onnx::Onnx,
}

fn fail(path: &Path, reason: impl Into<String>) -> DbtorError {
    DbtorError::Block {
        path: path.to_path_buf(),
        reason: format!("fast path: {}", reason.into()),
    }
}

fn read_proto(path: &Path) -> Result<pb::ModelProto, DbtorError> {
    tract_onnx::onnx()
        .proto_model_for_path(path)
        .map_err(|e| fail(path, format!("{e:#}")))
}

impl<'a> Graph<'a> {
    fn new(path: &Path, m: &'a pb::ModelProto) -> Result<Self, DbtorError> {
        let g = m
            .graph
            .as_ref()
            .ok_or_else(|| fail(path, "the file has no graph"))?;
        let mut producers = HashMap::new();
        for n in &g.node {
            for o in &n.output {
                producers.insert(o.as_str(), n);
            }
        }
        let inits = g.initializer.iter().map(|t| (t.name.as_str(), t)).collect();
        let inputs: Vec<&str> = g.input.iter().map(|i| i.name.as_str()).collect();
        if inputs.len() != 2 || g.output.len() != 1 {
            return Err(fail(
                path,
                format!(
                    "expected 2 inputs (state, aux) and 1 output, found {} and {}",
                    inputs.len(),
                    g.output.len()
                ),
            ));
        }
        Ok(Self {
            path: path.to_path_buf(),
            producers,
            inits,
            inputs,
            output: g.output[0].name.as_str(),
            onnx: tract_onnx::onnx(),
        })
    }

    fn err(&self, reason: impl Into<String>) -> DbtorError {
        fail(&self.path, reason)
    }

    /// The node producing `name`, which must be an `op`.
    fn node(&self, name: &str, op: &str) -> Result<&'a pb::NodeProto, DbtorError> {
        match self.producers.get(name) {
            Some(n) if n.op_type == op => Ok(n),
            Some(n) => Err(self.err(format!(
                "{name:?} is made by a {} node, expected {op}",
                n.op_type
            ))),
            None => Err(self.err(format!("{name:?} is not made by any node, expected {op}"))),
        }
    }

    fn input<'n>(&self, n: &'n pb::NodeProto, k: usize) -> Result<&'n str, DbtorError> {
        n.input
            .get(k)
            .map(|s| s.as_str())
            .ok_or_else(|| self.err(format!("{} node {:?} lacks input {k}", n.op_type, n.name)))
    }

    fn tensor(&self, name: &str) -> Result<Tensor, DbtorError> {
        let t = self
            .inits
            .get(name)
            .ok_or_else(|| self.err(format!("{name:?} is not an initializer")))?;
        tract_onnx::tensor::load_tensor(&*self.onnx.provider, t, None)
            .map_err(|e| self.err(format!("initializer {name:?}: {e:#}")))
    }

    fn values<T: Datum + Copy>(&self, name: &str) -> Result<Vec<T>, DbtorError> {
        let t = self.tensor(name)?;
        let v = t.to_plain_array_view::<T>().map_err(|e| {
            self.err(format!(
                "initializer {name:?} is {:?}, expected {:?}: {e:#}",
                t.datum_type(),
                T::datum_type()
            ))
        })?;
        Ok(v.iter().copied().collect())
    }

    fn f32s(&self, name: &str) -> Result<Vec<f32>, DbtorError> {
        self.values::<f32>(name)
    }

    /// Scale and zero point of a Q or DQ node (per tensor, int8).
    fn qparams(&self, n: &pb::NodeProto) -> Result<QuantParams, DbtorError> {
        let s = self.f32s(self.input(n, 1)?)?;
        let z = self.values::<i8>(self.input(n, 2)?).map_err(|e| {
            self.err(format!(
                "{} {:?}: the fast path runs int8 activations (export.py's QInt8): {e}",
                n.op_type, n.name
            ))
        })?;
        if s.len() != 1 || z.len() != 1 {
            return Err(self.err(format!(
                "{} {:?}: per-tensor activation quantization expected",
                n.op_type, n.name
            )));
        }
        Ok(QuantParams {
            scale: s[0],
            zero_point: z[0],
        })
    }

    /// `name = DQ(Q(x))`: `(x, Some(params))`; any other `name`: `(name, None)`.
    fn maybe_qdq(&self, name: &'a str) -> Result<(&'a str, Option<QuantParams>), DbtorError> {
        match self.producers.get(name) {
            Some(n) if n.op_type == "DequantizeLinear" => {
                let (x, q) = self.qdq(name)?;
                Ok((x, Some(q)))
            }
            _ => Ok((name, None)),
        }
    }

    /// `name = DQ(Q(x))` with one quantization: returns `(x, params)`.
    fn qdq(&self, name: &str) -> Result<(&'a str, QuantParams), DbtorError> {
        let dq = self.node(name, "DequantizeLinear")?;
        let q = self.node(self.input(dq, 0)?, "QuantizeLinear")?;
        let (a, b) = (self.qparams(dq)?, self.qparams(q)?);
        if a != b {
            return Err(self.err(format!(
                "QuantizeLinear {:?} and DequantizeLinear {:?} disagree",
                q.name, dq.name
            )));
        }
        let x = self.input(q, 0)?;
        Ok((x, a))
    }

    fn check_conv(&self, n: &pb::NodeProto) -> Result<(), DbtorError> {
        for a in &n.attribute {
            let ok = match a.name.as_str() {
                "kernel_shape" => a.ints == [3, 3],
                "pads" => a.ints == [1, 1, 1, 1],
                "strides" | "dilations" => a.ints == [1, 1],
                "group" => a.i == 1,
                _ => false,
            };
            if !ok {
                return Err(self.err(format!(
                    "Conv {:?}: attribute {} = {:?} (the fast path runs 3x3, pad 1, stride 1, dilation 1, group 1)",
                    n.name, a.name, if a.ints.is_empty() { vec![a.i] } else { a.ints.clone() }
                )));
            }
        }
        if n.input.len() != 3 {
            return Err(self.err(format!("Conv {:?} has no bias", n.name)));
        }
        Ok(())
    }

    fn prelu_slope(&self, n: &pb::NodeProto, out_ch: usize) -> Result<Vec<f32>, DbtorError> {
        let s = self.f32s(self.input(n, 1)?)?;
        if s.len() != out_ch {
            return Err(self.err(format!(
                "PRelu {:?} has {} slopes for {out_ch} channels",
                n.name,
                s.len()
            )));
        }
        Ok(s)
    }

    fn channels(&self, weight: &str, n: usize) -> Result<(usize, usize), DbtorError> {
        let t = self
            .inits
            .get(weight)
            .ok_or_else(|| self.err(format!("{weight:?} is not an initializer")))?;
        match t.dims.as_slice() {
            [o, i, 3, 3] if (*o * *i * 9) as usize == n => Ok((*o as usize, *i as usize)),
            d => Err(self.err(format!(
                "weight {weight:?} has shape {d:?}, expected [out, in, 3, 3]"
            ))),
        }
    }
}

fn conv_f32(g: &Graph<'_>, conv: &pb::NodeProto) -> Result<Conv3x3, DbtorError> {
    g.check_conv(conv)?;
    let (wn, bn) = (g.input(conv, 1)?, g.input(conv, 2)?);
    let weight = g.f32s(wn)?;
    let (out_ch, in_ch) = g.channels(wn, weight.len())?;
    Ok(Conv3x3 {
        in_ch,
        out_ch,
        weight,
        bias: g.f32s(bn)?,
        prelu: None,
    })
}

/// The fp32 block of `path`.
pub(crate) fn fp32_block(
    path: &Path,
    state_ch: usize,
    aux_ch: usize,
) -> Result<BlockWeights, DbtorError> {
    let proto = read_proto(path)?;
    let g = Graph::new(path, &proto)?;
    let (state, aux) = (g.inputs[0], g.inputs[1]);
    let add = g.node(g.output, "Add")?;
    let c3 = match (g.input(add, 0)?, g.input(add, 1)?) {
        (a, b) if a == state => b,
        (a, b) if b == state => a,
        _ => return Err(g.err("the output Add does not add the state input")),
    };
    let conv3 = g.node(c3, "Conv")?;
    let p2 = g.node(g.input(conv3, 0)?, "PRelu")?;
    let conv2 = g.node(g.input(p2, 0)?, "Conv")?;
    let p1 = g.node(g.input(conv2, 0)?, "PRelu")?;
    let conv1 = g.node(g.input(p1, 0)?, "Conv")?;
    let cat = g.node(g.input(conv1, 0)?, "Concat")?;
    if cat.input != [state, aux] {
        return Err(g.err("the first Conv does not read Concat(state, aux)"));
    }
    let mut l1 = conv_f32(&g, conv1)?;
    let mut l2 = conv_f32(&g, conv2)?;
    let l3 = conv_f32(&g, conv3)?;
    l1.prelu = Some(g.prelu_slope(p1, l1.out_ch)?);
    l2.prelu = Some(g.prelu_slope(p2, l2.out_ch)?);
    let b = BlockWeights {
        state_ch,
        aux_ch,
        layers: [l1, l2, l3],
    };
    b.check().map_err(|e| g.err(e.to_string()))?;
    Ok(b)
}

/// A Conv of the QDQ graph: int8 weights per output channel, int32 bias,
/// both behind DequantizeLinear.
fn conv_int8(
    g: &Graph<'_>,
    conv: &pb::NodeProto,
    q_out: Option<QuantParams>,
    q_act: Option<QuantParams>,
) -> Result<Int8Conv, DbtorError> {
    g.check_conv(conv)?;
    let wdq = g.node(g.input(conv, 1)?, "DequantizeLinear")?;
    let wn = g.input(wdq, 0)?;
    let weight = g.values::<i8>(wn)?;
    let (out_ch, in_ch) = g.channels(wn, weight.len())?;
    let weight_scale = g.f32s(g.input(wdq, 1)?)?;
    let wz = g.values::<i8>(g.input(wdq, 2)?)?;
    if weight_scale.len() != out_ch || wz.iter().any(|z| *z != 0) {
        return Err(g.err(format!(
            "Conv {:?}: weights must be symmetric int8 with one scale per output channel",
            conv.name
        )));
    }
    let bdq = g.node(g.input(conv, 2)?, "DequantizeLinear")?;
    let bq = g.values::<i32>(g.input(bdq, 0)?)?;
    let bs = g.f32s(g.input(bdq, 1)?)?;
    let bz = g.values::<i32>(g.input(bdq, 2)?)?;
    if bq.len() != out_ch || bs.len() != out_ch || bz.len() != out_ch {
        return Err(g.err(format!(
            "Conv {:?}: bias quantization is not per output channel",
            conv.name
        )));
    }
    // DequantizeLinear: (q - zp) * scale, in float.
    let bias = (0..out_ch)
        .map(|o| (bq[o] - bz[o]) as f32 * bs[o])
        .collect();
    Ok(Int8Conv {
        in_ch,
        out_ch,
        weight,
        weight_scale,
        bias,
        prelu: None,
        q_out,
        q_act,
    })
}

/// The static int8 (QDQ) block of `path`, in any of export.py's forms.
pub(crate) fn int8_block(
    path: &Path,
    state_ch: usize,
    aux_ch: usize,
) -> Result<Int8BlockWeights, DbtorError> {
    let proto = read_proto(path)?;
    let g = Graph::new(path, &proto)?;
    let (state, aux) = (g.inputs[0], g.inputs[1]);
    // The residual: quantized, DQ(Q(Add(DQ(Q(state)), c3))), or float,
    // Add(state, c3), c3 quantized or not.
    let (sum, q_result) = g.maybe_qdq(g.output)?;
    let add = g.node(sum, "Add")?;
    let (x, qx) = g.maybe_qdq(g.input(add, 0)?)?;
    let (y, qy) = g.maybe_qdq(g.input(add, 1)?)?;
    let (c3, q_state_add, q_out3) = match (x, y) {
        (a, b) if a == state => (b, qx, qy),
        (a, b) if b == state => (a, qy, qx),
        _ => return Err(g.err("the output Add does not add the state input")),
    };
    if q_result.is_some() != q_state_add.is_some() {
        return Err(g.err(
            "the residual sum must be quantized with the quantized state, or float with the raw state",
        ));
    }
    let conv3 = g.node(c3, "Conv")?;
    let (p2o, q_act2) = g.qdq(g.input(conv3, 0)?)?;
    let p2 = g.node(p2o, "PRelu")?;
    let (c2, q_out2) = g.maybe_qdq(g.input(p2, 0)?)?;
    let conv2 = g.node(c2, "Conv")?;
    let (p1o, q_act1) = g.qdq(g.input(conv2, 0)?)?;
    let p1 = g.node(p1o, "PRelu")?;
    let (c1, q_out1) = g.maybe_qdq(g.input(p1, 0)?)?;
    let conv1 = g.node(c1, "Conv")?;
    let (mut cat_out, q_cat) = g.qdq(g.input(conv1, 0)?)?;
    // The conv-inputs form's prescale: Mul(Concat(...), k), k [1, C, 1, 1].
    let mut prescale = None;
    if let Some(mul) = g.producers.get(cat_out).filter(|n| n.op_type == "Mul") {
        let (a, b) = (g.input(mul, 0)?, g.input(mul, 1)?);
        let (x, k) = if g.inits.contains_key(b) {
            (a, b)
        } else {
            (b, a)
        };
        let dims = g.inits.get(k).map(|t| t.dims.clone()).unwrap_or_default();
        let c = (state_ch + aux_ch) as i64;
        if dims != [1, c, 1, 1] {
            return Err(g.err(format!(
                "the Mul before the first Conv must scale each of the {c} concatenated channels by a constant [1, {c}, 1, 1], has {k:?} of shape {dims:?}"
            )));
        }
        prescale = Some(g.f32s(k)?);
        cat_out = x;
    }
    let cat = g.node(cat_out, "Concat")?;
    let (s_in, q_state) = g.maybe_qdq(g.input(cat, 0)?)?;
    let (a_in, q_aux) = g.maybe_qdq(g.input(cat, 1)?)?;
    if cat.input.len() != 2
        || s_in != state
        || a_in != aux
        || q_state_add.is_some_and(|q| Some(q) != q_state)
    {
        return Err(g.err(
            "the first Conv does not read Concat(state, aux) (each quantized or not) with the residual's state quantization",
        ));
    }
    let mut l1 = conv_int8(&g, conv1, q_out1, Some(q_act1))?;
    let mut l2 = conv_int8(&g, conv2, q_out2, Some(q_act2))?;
    let l3 = conv_int8(&g, conv3, q_out3, None)?;
    l1.prelu = Some(g.prelu_slope(p1, l1.out_ch)?);
    l2.prelu = Some(g.prelu_slope(p2, l2.out_ch)?);
    let b = Int8BlockWeights {
        state_ch,
        aux_ch,
        q_state,
        q_aux,
        prescale,
        q_cat,
        layers: [l1, l2, l3],
        q_result,
    };
    b.check().map_err(|e| g.err(e.to_string()))?;
    Ok(b)
}
