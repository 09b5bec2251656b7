//! Choosing the compute device by name, for the command line and configuration files.
//!
//! Every model, trainer and server path takes a [`Device`]; this module turns the names users
//! write (`cpu`, `cuda`, `cuda:1`) into one, with a clear error where the build cannot serve
//! the request. CUDA needs the binary built with `--features cuda` (the CUDA toolkit at build
//! time comes from `deploy/cuda/toolkit.sh`); without it, asking for `cuda` is an error, never
//! a silent fall back to the CPU.

use candle_core::Device;

use crate::ModelError;

/// The device names [`device_from_name`] accepts, for help texts.
pub const DEVICE_NAMES: &str = "cpu, cuda (the first GPU) or cuda:N";

/// Whether this build can run on CUDA devices (compiled with the `cuda` feature).
pub fn cuda_compiled() -> bool {
    candle_core::utils::cuda_is_available()
}

/// A device a name selects, before any driver is opened.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum DeviceSpec {
    /// The host CPU.
    Cpu,
    /// The CUDA device with this ordinal.
    Cuda(usize),
}

/// Parses a device name and checks that this build can serve it, without opening the device.
fn parse_device_name(name: &str) -> Result<DeviceSpec, ModelError> {
    let spec = name.trim().to_ascii_lowercase();
    let ordinal = match spec.as_str() {
        "cpu" => return Ok(DeviceSpec::Cpu),
        "cuda" | "gpu" => 0,
        s => match s.strip_prefix("cuda:").map(str::parse::<usize>) {
            Some(Ok(n)) => n,
            _ => {
                return Err(ModelError::InvalidInput(format!(
                    "device {name:?}: expected {DEVICE_NAMES}"
                )));
            }
        },
    };
    if !cuda_compiled() {
        return Err(ModelError::InvalidInput(format!(
            "device {name:?}: this build has no CUDA support; rebuild with \
             `cargo build --release --features cuda` (the CUDA toolkit comes from \
             `deploy/cuda/toolkit.sh`), or use cpu"
        )));
    }
    Ok(DeviceSpec::Cuda(ordinal))
}

/// Checks a device name as [`device_from_name`] does, but without opening the device (no
/// driver context is created), for validating configuration before start-up.
///
/// Errors as [`device_from_name`] does, except that an ordinal the driver cannot open is only
/// found when the device is opened.
pub fn check_device_name(name: &str) -> Result<(), ModelError> {
    parse_device_name(name).map(|_| ())
}

/// The device a name selects: `cpu`; `cuda` or `gpu` (ordinal 0); `cuda:N` (ordinal `N`).
/// Case and surrounding space are ignored.
///
/// Errors with [`ModelError::InvalidInput`] on any other name, on a `cuda` device in a build
/// without the `cuda` feature (naming the rebuild command), and when the driver cannot open
/// the ordinal.
pub fn device_from_name(name: &str) -> Result<Device, ModelError> {
    match parse_device_name(name)? {
        DeviceSpec::Cpu => Ok(Device::Cpu),
        DeviceSpec::Cuda(ordinal) => Device::new_cuda(ordinal).map_err(|e| {
            let e = e.to_string();
            let why = if e.contains("STUB_LIBRARY") {
                " (this machine has no NVIDIA driver: the library answering is the build stub)"
            } else {
                ""
            };
            // The hint first: candle's message may carry a backtrace.
            ModelError::InvalidInput(format!("device {name:?}: cannot open it{why}: {e}"))
        }),
    }
}

/// The name [`device_from_name`] reads back as `device` (`cpu`, `cuda:N`, `metal:N`).
pub fn device_name(device: &Device) -> String {
    match device.location() {
        candle_core::DeviceLocation::Cpu => "cpu".to_string(),
        candle_core::DeviceLocation::Cuda { gpu_id } => format!("cuda:{gpu_id}"),
        candle_core::DeviceLocation::Metal { gpu_id } => format!("metal:{gpu_id}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cpu_is_always_available_and_names_round_trip() {
        for name in ["cpu", " CPU "] {
            let d = device_from_name(name).unwrap();
            assert!(d.is_cpu());
            assert_eq!(device_name(&d), "cpu");
            assert!(check_device_name(name).is_ok());
        }
    }

    #[test]
    fn unknown_names_are_refused_with_the_accepted_ones() {
        for name in ["tpu", "cuda:x", "cuda:-1", ""] {
            let e = device_from_name(name).unwrap_err().to_string();
            assert!(e.contains(DEVICE_NAMES), "{name}: {e}");
            let checked = check_device_name(name).unwrap_err().to_string();
            assert_eq!(checked, e, "{name}: checking and opening disagree");
        }
    }

    #[test]
    fn cuda_without_the_feature_says_how_to_get_it() {
        if cuda_compiled() {
            return;
        }
        for name in ["cuda", "gpu", "cuda:1"] {
            let e = device_from_name(name).unwrap_err().to_string();
            assert!(e.contains("--features cuda"), "{name}: {e}");
            let checked = check_device_name(name).unwrap_err().to_string();
            assert_eq!(checked, e, "{name}: checking and opening disagree");
        }
    }
}
