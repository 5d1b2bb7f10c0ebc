//! Any byte string given to the lights-file reader gives lights or a typed error within the
//! budget; lights read are finite with non-negative power, and formatting them reads back the
//! same positions and powers.
#![no_main]

use libfuzzer_sys::fuzz_target;
use prt_trace::manylight::{LightsBudget, format_lights, parse_lights};

fuzz_target!(|data: &[u8]| {
    let budget = LightsBudget::new(1 << 16);
    if let Ok(lights) = parse_lights(data, &budget) {
        assert!(!lights.is_empty());
        assert!(lights.len() as u64 * budget.bytes_per_light <= budget.max_bytes);
        for v in &lights {
            assert!(v.position.is_finite() && v.normal.is_finite() && v.flux.is_finite());
            assert!(v.flux.min_element() >= 0.0 && v.flux.max_element() > 0.0);
        }
        let again = parse_lights(format_lights(&lights).as_bytes(), &budget).expect("round trip");
        assert_eq!(again.len(), lights.len());
        for (a, b) in again.iter().zip(&lights) {
            assert_eq!((a.position, a.flux), (b.position, b.flux));
        }
    }
});
