//! The float reference of the QDQ graph: the block's weights as
//! quantized, and the graph evaluated operation by operation.

use super::*;

/// One quantized 3x3 convolution.
#[derive(Clone, Debug, PartialEq)]
pub struct Int8Conv {
    /// Input channels.
    pub in_ch: usize,
    /// Output channels.
    pub out_ch: usize,
    /// `[out][in][3][3]` int8 weights (zero point 0).
    pub weight: Vec<i8>,
    /// `[out]` weight scales.
    pub weight_scale: Vec<f32>,
    /// `[out]` the dequantized bias.
    pub bias: Vec<f32>,
    /// `[out]` PReLU slopes (float in the graph), if a PReLU follows.
    pub prelu: Option<Vec<f32>>,
    /// The quantization of the convolution's output, if any (`None`: the
    /// dequantized sum goes on in float).
    pub q_out: Option<QuantParams>,
    /// The quantization of the PReLU's output, if a PReLU follows.
    pub q_act: Option<QuantParams>,
}

/// The quantized block: layers and the activation quantizations around them.
#[derive(Clone, Debug, PartialEq)]
pub struct Int8BlockWeights {
    /// State channels.
    pub state_ch: usize,
    /// Aux channels.
    pub aux_ch: usize,
    /// Quantization of the state input, if any.
    pub q_state: Option<QuantParams>,
    /// Quantization of the aux input, if any.
    pub q_aux: Option<QuantParams>,
    /// `[state_ch + aux_ch]` factors the concatenation is multiplied by
    /// before its quantization, if any.
    pub prescale: Option<Vec<f32>>,
    /// Quantization of the (prescaled) concatenation.
    pub q_cat: QuantParams,
    /// The three convolutions.
    pub layers: [Int8Conv; 3],
    /// Quantization of the block's output, `DQ(Q(DQ(Q(state)) + c3))`; `None`:
    /// the float residual `state + c3`.
    pub q_result: Option<QuantParams>,
}

impl Int8BlockWeights {
    /// Check that the layers chain and every scale is usable.
    pub fn check(&self) -> Result<(), ConvError> {
        let bad = |r: String| Err(ConvError::Weights(r));
        if let Some(q) = self.q_state {
            q.check("state")?;
        }
        if let Some(q) = self.q_aux {
            q.check("aux")?;
        }
        self.q_cat.check("concatenation")?;
        if let Some(k) = &self.prescale {
            if k.len() != self.state_ch + self.aux_ch {
                return bad(format!(
                    "prescale: {} factors for {} channels",
                    k.len(),
                    self.state_ch + self.aux_ch
                ));
            }
            if k.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
                return bad("prescale: a factor is not a positive number".into());
            }
        }
        if let Some(q) = self.q_result {
            q.check("output")?;
            if self.q_state.is_none() {
                return bad(
                    "the quantized residual adds the quantized state, which is not quantized"
                        .into(),
                );
            }
        }
        let mut cin = self.state_ch + self.aux_ch;
        for (k, l) in self.layers.iter().enumerate() {
            let name = format!("layer {}", k + 1);
            if l.in_ch != cin || l.in_ch == 0 || l.out_ch == 0 {
                return bad(format!("{name}: takes {} channels, is fed {cin}", l.in_ch));
            }
            if l.weight.len() != l.out_ch * l.in_ch * 9
                || l.weight_scale.len() != l.out_ch
                || l.bias.len() != l.out_ch
                || l.prelu.as_ref().is_some_and(|p| p.len() != l.out_ch)
            {
                return bad(format!(
                    "{name}: weight, scale, bias or slope lengths do not match {} -> {}",
                    l.in_ch, l.out_ch
                ));
            }
            if l.weight_scale.iter().any(|s| !(s.is_finite() && *s > 0.0))
                || l.bias.iter().any(|b| !b.is_finite())
                || l.prelu
                    .as_ref()
                    .is_some_and(|p| p.iter().any(|s| !s.is_finite()))
            {
                return bad(format!(
                    "{name}: a weight scale, bias or slope is not finite (or a scale not positive)"
                ));
            }
            if let Some(q) = l.q_out {
                q.check(&format!("{name} output"))?;
            }
            let last = k == 2;
            if last != l.prelu.is_none() || l.prelu.is_some() != l.q_act.is_some() {
                return bad(format!(
                    "{name}: expected PReLU (with its quantization) after layers 1 and 2 only"
                ));
            }
            if let Some(q) = l.q_act {
                q.check(&format!("{name} PReLU"))?;
            }
            cin = l.out_ch;
        }
        if cin != self.state_ch {
            return bad(format!(
                "layer 3 gives {cin} channels, the state has {}",
                self.state_ch
            ));
        }
        Ok(())
    }

    /// Integer multiply-adds x 2 of one block on `h x w`.
    pub fn ops(&self, h: usize, w: usize) -> f64 {
        let px = (h * w) as f64;
        self.layers
            .iter()
            .map(|l| 18.0 * (l.in_ch * l.out_ch) as f64 * px)
            .sum()
    }
}

/// The float semantics of the QDQ graph, transcribed (CHW, f64 sums over the
/// dequantized values): the reference of the integer kernels.
pub fn reference_int8_block(
    b: &Int8BlockWeights,
    state: &[f32],
    aux: &[f32],
    h: usize,
    w: usize,
) -> Result<Vec<f32>, ConvError> {
    b.check()?;
    let n = h * w;
    if state.len() != b.state_ch * n || aux.len() != b.aux_ch * n {
        return Err(ConvError::Shape("state or aux length".into()));
    }
    let fake = |q: Option<QuantParams>, v: f32| q.map_or(v, |q| q.fake(v));
    let s1: Vec<f32> = state.iter().map(|&v| fake(b.q_state, v)).collect();
    let mut x: Vec<f32> = s1
        .iter()
        .copied()
        .chain(aux.iter().map(|&v| fake(b.q_aux, v)))
        .enumerate()
        .map(|(k, v)| {
            let v = b.prescale.as_ref().map_or(v, |p| v * p[k / n]);
            b.q_cat.fake(v)
        })
        .collect();
    for l in &b.layers {
        let fl = crate::Conv3x3 {
            in_ch: l.in_ch,
            out_ch: l.out_ch,
            weight: l
                .weight
                .iter()
                .enumerate()
                .map(|(k, &q)| q as f32 * l.weight_scale[k / (l.in_ch * 9)])
                .collect(),
            bias: l.bias.clone(),
            prelu: None,
        };
        let y = crate::reference_conv(&fl, &x, h, w);
        x = y
            .iter()
            .enumerate()
            .map(|(k, &v)| {
                let v = fake(l.q_out, v);
                match (&l.prelu, l.q_act) {
                    (Some(p), Some(q)) => q.fake(if v < 0.0 { v * p[k / n] } else { v }),
                    _ => v,
                }
            })
            .collect();
    }
    Ok(match b.q_result {
        Some(q) => s1.iter().zip(&x).map(|(s, c)| q.fake(s + c)).collect(),
        None => state.iter().zip(&x).map(|(s, c)| s + c).collect(),
    })
}
