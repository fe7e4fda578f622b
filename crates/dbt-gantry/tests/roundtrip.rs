//! Property tests: every frame the codec can encode decodes to itself, fed
//! in arbitrary chunks; every register block that decodes re-encodes to the
//! same registers; and no input makes the decoders panic.

use dbt_gantry::frame::{encode, AcquisitionHeader, Decoder, Frame, Projection};
use dbt_gantry::registers;
use proptest::prelude::*;

fn header() -> impl Strategy<Value = AcquisitionHeader> {
    (
        "[A-Za-z0-9-]{1,64}",
        "[A-Za-z]{0,20}\\^[A-Za-z]{0,20}",
        "[1-9][0-9]{0,5}(\\.[1-9][0-9]{0,5}){1,6}",
        "[A-Z0-9]{0,16}",
        (1970u32..2100, 1u32..13, 1u32..29),
        (0u32..24, 0u32..60, 0u32..60),
        (100u32..1500, 200u32..490, 1u32..5000),
        (1u16..64, 1u16..64, 1u16..64),
        (
            prop_oneof![Just("L".to_string()), Just("R".to_string())],
            prop_oneof![
                Just(None),
                Just(Some("paper-cone".to_string())),
                "[a-z0-9-]{1,64}".prop_map(Some)
            ],
        ),
    )
        .prop_map(
            |(
                id,
                name,
                uid,
                acc,
                (y, m, d),
                (hh, mm, ss),
                (t, kv, mas),
                (p, r, c),
                (lat, system),
            )| {
                AcquisitionHeader {
                    patient_id: id,
                    patient_name: name,
                    study_uid: uid,
                    accession: acc,
                    study_date: format!("{y:04}{m:02}{d:02}"),
                    study_time: format!("{hh:02}{mm:02}{ss:02}"),
                    // Decimal values, as the gantry sends them (JSON floats).
                    thickness_mm: t as f64 / 10.0,
                    kvp: kv as f64 / 10.0,
                    mas_total: mas as f64 / 10.0,
                    projections: p,
                    rows: r,
                    columns: c,
                    laterality: lat,
                    system,
                    anode_filter: Some("W/Rh".into()),
                }
            },
        )
}

fn projection() -> impl Strategy<Value = Projection> {
    (0u16..64, -60.0f32..60.0, 1u16..6, 1u16..9).prop_flat_map(|(view, angle, rows, cols)| {
        let n = rows as usize * cols as usize;
        (
            proptest::collection::vec(any::<u16>(), n),
            proptest::collection::vec(1.0f32..70_000.0, n),
        )
            .prop_map(move |(counts, flat)| Projection {
                view,
                angle_deg: angle,
                rows,
                columns: cols,
                counts,
                flat,
            })
    })
}

fn frame() -> impl Strategy<Value = Frame> {
    prop_oneof![
        header().prop_map(Frame::Header),
        projection().prop_map(Frame::Projection),
        any::<u16>().prop_map(|projections| Frame::End { projections }),
        any::<u32>().prop_map(|seq| Frame::Ack { seq }),
        any::<u32>().prop_map(|seq| Frame::Nak { seq }),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn frames_round_trip_in_any_chunking(
        frames in proptest::collection::vec((frame(), any::<u32>()), 1..6),
        chunk in 1usize..700,
        garbage in proptest::collection::vec(any::<u8>(), 0..40),
    ) {
        // Garbage before the first frame (it holds no marker: none of its
        // bytes is 'D'), skipped by the resynchronisation.
        let garbage: Vec<u8> = garbage.into_iter().filter(|&b| b != b'D').collect();
        let mut bytes = garbage;
        for (f, seq) in &frames {
            bytes.extend(encode(f, *seq));
        }
        let mut d = Decoder::new();
        let mut got = Vec::new();
        for c in bytes.chunks(chunk) {
            d.push(c);
            while let Some(r) = d.next_frame() {
                if let Ok(f) = r {
                    got.push(f);
                }
            }
        }
        let want: Vec<(u32, Frame)> = frames.into_iter().map(|(f, s)| (s, f)).collect();
        prop_assert_eq!(got, want);
        prop_assert_eq!(d.pending(), 0);
    }

    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..4000), max in 0usize..5000) {
        let mut d = Decoder::with_max_payload(max);
        d.push(&bytes);
        let mut n = 0;
        while d.next_frame().is_some() {
            n += 1;
            prop_assert!(n <= bytes.len() + 1);
        }
    }

    #[test]
    fn register_blocks_that_decode_re_encode_to_themselves(r in proptest::collection::vec(any::<u16>(), registers::COUNT)) {
        if let Ok(v) = registers::decode(&r) {
            let again = registers::encode(&v);
            prop_assert_eq!(registers::decode(&again).unwrap(), v);
        }
    }

    #[test]
    fn valid_register_values_round_trip(
        state in 0u16..6, t in 0u16..2000, force in any::<u16>(), kv in prop_oneof![Just(0u16), 150u16..=500],
        mas in any::<u16>(), anode in 1u16..=5, n in 0u16..100, a0 in -900i16..=900, a1 in -900i16..=900,
        cur in 0u16..100, lat in 1u16..=2, view in 1u16..=4, fault in any::<u16>(),
    ) {
        let r = [registers::INTERFACE_VERSION, state, t, force, kv, mas, anode, n, a0 as u16, a1 as u16,
                 if state == 3 && n > 0 { cur % n } else { cur }, lat | (view << 8), fault];
        let v = registers::decode(&r).unwrap();
        prop_assert_eq!(registers::encode(&v).to_vec(), r.to_vec());
    }
}
