//! Memory a call is about to allocate, checked before it is. A failed allocation in Rust aborts
//! the whole process (`handle_alloc_error`), so a size that cannot be held — an overflowing
//! product, or more bytes than the machine has available — is refused here as an `InvalidInput`
//! error naming the argument (Python: `InputError`).

use crate::error::{invalid_input, Result};

/// Bytes of memory available to allocate: `MemAvailable` of `/proc/meminfo` where it can be
/// read (Linux), else the address space's limit (`isize::MAX`, Rust's own cap).
pub fn available_bytes() -> u64 {
    std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|s| {
            s.lines().find_map(|l| l.strip_prefix("MemAvailable:").and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok()))
        })
        .map_or(isize::MAX as u64, |kb| kb.saturating_mul(1024))
}

/// Sizes up to this many bytes are allowed without reading `/proc/meminfo` (a read costs about
/// 30 µs, more than a planner's edge check; the planner asks once per edge): a machine without
/// 64 MiB to spare has failed before the call.
const ALWAYS_FITS: u64 = 1 << 26;

/// The element count `dims` multiply to, when that many elements of `elem_bytes` fit in the
/// memory available; else an error that names `what` (the argument, as the caller spells it),
/// the dimensions and the bytes needed.
pub fn check(what: &str, dims: &[usize], elem_bytes: usize) -> Result<usize> {
    let count = dims.iter().try_fold(1usize, |a, &d| a.checked_mul(d));
    let bytes = count.and_then(|n| n.checked_mul(elem_bytes)).map(|b| b as u64);
    if let (Some(n), Some(b)) = (count, bytes) {
        if b <= ALWAYS_FITS {
            return Ok(n);
        }
    }
    let available = available_bytes();
    match (count, bytes) {
        (Some(n), Some(b)) if b <= available => Ok(n),
        _ => {
            let need = dims.iter().map(|&d| d as f64).product::<f64>() * elem_bytes as f64;
            invalid_input(format!(
                "{what} is too large: {dims:?} x {elem_bytes} bytes needs {:.3e} GB, and {:.3} GB of memory is available",
                need / 1e9,
                available as f64 / 1e9
            ))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn regression_absurd_sizes_are_errors_not_aborts() {
        assert!(check("n", &[1 << 40, 9], 8).is_err());
        assert!(check("n", &[usize::MAX, 2], 8).is_err()); // the product overflows
        assert_eq!(check("n", &[1000, 9], 8).unwrap(), 9000);
        let e = check("steps", &[3, 1 << 40, 7], 8).unwrap_err().to_string();
        assert!(e.starts_with("steps is too large"), "{e}");
    }
}
