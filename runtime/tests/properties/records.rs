//! Postcard round trips of the weights file's records.

use super::*;

fn finite_f32() -> impl Strategy<Value = f32> {
    prop_oneof![
        any::<f32>().prop_filter("finite", |x| x.is_finite()),
        Just(0.0),
        Just(-0.0)
    ]
}

fn act_quant() -> impl Strategy<Value = ActQuantRecord> {
    (finite_f32(), any::<i8>()).prop_map(|(scale, zero_point)| ActQuantRecord { scale, zero_point })
}

fn input_quant() -> impl Strategy<Value = InputQuantRecord> {
    (finite_f32(), any::<i8>(), any::<i32>(), any::<i8>()).prop_map(
        |(scale_m, zero_point, multiplier, shift)| InputQuantRecord {
            scale_m,
            zero_point,
            multiplier,
            shift,
        },
    )
}

fn bytes(max: usize) -> impl Strategy<Value = Vec<u8>> {
    prop::collection::vec(any::<u8>(), 0..max)
}

/// Encodes with postcard into a stack buffer (the runtime has no allocator) and checks that
/// decoding gives the value back and consumes every byte.
fn round_trip<'a, T>(value: &T, buf: &'a mut [u8]) -> Result<T, TestCaseError>
where
    T: serde::Serialize + serde::Deserialize<'a> + PartialEq + core::fmt::Debug,
{
    let used = postcard::to_slice(value, buf).map_err(|e| TestCaseError::fail(format!("{e}")))?;
    let (back, rest) =
        postcard::take_from_bytes::<T>(used).map_err(|e| TestCaseError::fail(format!("{e}")))?;
    prop_assert!(rest.is_empty());
    prop_assert_eq!(&back, value);
    Ok(back)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2048))]

    #[test]
    fn envelope_round_trips(version in any::<u16>(), payload in bytes(600), crc in any::<[u8; 4]>()) {
        let envelope = Envelope { magic: *b"WLWM", version, payload: &payload, crc32_le: crc };
        let mut buf = [0u8; 1024];
        round_trip(&envelope, &mut buf)?;
    }

    #[test]
    fn input_records_round_trip(rows in any::<u16>(), cols in any::<u16>(), q in input_quant()) {
        let mut buf = [0u8; 64];
        round_trip(&InputRecord { rows, cols, height: q }, &mut buf)?;
        let mut buf = [0u8; 64];
        round_trip(&q, &mut buf)?;
    }

    #[test]
    fn conv_records_round_trip(shape in any::<(u16, u16, u8, u8, u8, bool)>(), output in act_quant(),
                               weights in bytes(300), bias in bytes(40), multipliers in bytes(40),
                               shifts in bytes(10)) {
        let (in_channels, out_channels, kernel, stride, padding, relu) = shape;
        let record = ConvRecord {
            in_channels, out_channels, kernel, stride, padding, relu, output,
            weights: &weights, bias: &bias, multipliers: &multipliers, shifts: &shifts,
        };
        let mut buf = [0u8; 1024];
        round_trip(&record, &mut buf)?;
    }

    #[test]
    fn dense_records_round_trip(shape in any::<(u16, u16, bool)>(), output in act_quant(),
                                weights in bytes(300), bias in bytes(40), multipliers in bytes(40),
                                shifts in bytes(10), head in any::<bool>()) {
        let (in_features, out_features, relu) = shape;
        let record = DenseRecord {
            in_features, out_features, relu, output,
            weights: &weights, bias: &bias, multipliers: &multipliers, shifts: &shifts,
        };
        let mut buf = [0u8; 1024];
        round_trip(&record, &mut buf)?;
        // The value head is stored as an Option.
        let optional = head.then_some(record);
        let mut buf = [0u8; 1024];
        round_trip(&optional, &mut buf)?;
    }
}
