//! The float network as trained, batched through burn, behind the decision stack's policy
//! interface (`wheelleg_stack::policy::BatchPolicy`, which the int8 runtime policy implements
//! too): evaluation and calibration rollouts take either.

use crate::error::TrainError;
use crate::network::{to_vec, Net};
use crate::network_f32::NetworkF32;
use burn::tensor::Device;
use wheelleg_stack::policy::BatchPolicy;

/// The float network as trained, batched through burn.
pub struct FloatPolicy {
    net: Net,
}

impl FloatPolicy {
    /// Copies `network` to `device` for inference.
    pub fn new(network: &NetworkF32, device: &Device) -> Result<FloatPolicy, TrainError> {
        Ok(FloatPolicy {
            net: Net::new(network, device, false)?,
        })
    }
}

impl BatchPolicy for FloatPolicy {
    fn log_probs(&self, heights_m: &[f32], states: &[f32], n: usize) -> Result<Vec<f32>, String> {
        let forward = self.net.forward(heights_m.to_vec(), states.to_vec(), n);
        Ok(to_vec(forward.log_probs))
    }

    fn kind(&self) -> &'static str {
        "float"
    }
}
