//! Mutation fuzzers over the .zmx and AGF readers: no panic, errors name a line.

use super::*;

/// Mutations that a fuzzer would find: the reader must never panic, every error has a message,
/// and every lens it accepts traces, writes and reads back.
#[test]
fn fuzz_the_zmx_reader() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    let perturbed = {
        let lens = Lens::load("lens1").unwrap();
        let p: Perturbation = serde_json::from_str(
            r#"{"elements": [{"element": 1, "decenter_mm": [0.02, -0.01], "tilt_deg": [0.1, 0.2, 0]}]}"#,
        )
        .unwrap();
        let (l, adj) = p.apply(&lens).unwrap();
        zemax::to_string(&l.with_adjustments(&adj).unwrap(), None)
    };
    let bases = [
        text("lens1.zmx"),
        text("lens2.zmx"),
        text("asphere.zmx"),
        text("cooke-triplet.zmx"),
        perturbed,
    ];
    let junk = [
        "",
        "x",
        "-1",
        "0",
        "-0",
        "1e308",
        "-1e308",
        "INFINITY",
        "NaN",
        "inf",
        "1e-320",
        "99999999999999999999",
        "4294967296",
        "1.5.2",
        "___BLANK",
        "MIRROR",
        "COORDBRK",
        "EVENASPH",
    ];
    let inserts = [
        "SURF 3",
        "TYPE COORDBRK",
        "TYPE EVENASPH",
        "PARM 6 1",
        "PARM 3 89.9",
        "PARM 4 -120",
        "STOP",
        "GLAS MIRROR",
        "GLAS ___BLANK 1 0 0.5 0",
        "GLAS ___BLANK 1 0 1.5 0",
        "GLAS N-SF5",
        "DISZ INFINITY",
        "DISZ -1000",
        "UNIT IN",
        "UNIT METER",
        "FTYP 3 0 99999999 99999 0",
        "FTYP 1 0 2 1",
        "PWAV 0",
        "WAVM 99 0.5 1",
        "WAVL 0.5 0.6",
        "CURV 1e9",
        "CURV -0.2",
        "DIAM -3",
        "DIAM 1e300 1",
        "CONI -1e10",
        "ENPD 1e9",
        "ENPD -2",
        "FNUM 0",
        "OBNA 0.5",
        "OBNA 2",
        "FLOA",
        "NOTE 0 tolray rgb_nm=1,2,3 sensor_res=0,1e20",
        "NOTE 0 tolray primary_nm=x",
        "XFLN 1 2 3",
        "VDXN 1 1",
        "MODE SEQ",
        "SURF 0",
    ];
    let mut accepted = 0;
    for it in 0..6000 {
        let base = &bases[it % bases.len()];
        let mut lines: Vec<String> = base.lines().map(str::to_string).collect();
        let bytes: Vec<u8> = match rng.random_range(0..5) {
            0 => {
                // Bytes: delete, duplicate or replace a few.
                let mut b = base.as_bytes().to_vec();
                for _ in 0..rng.random_range(1..4) {
                    let i = rng.random_range(0..b.len());
                    match rng.random_range(0..3) {
                        0 => {
                            b.remove(i);
                        }
                        1 => b.insert(i, b[i]),
                        _ => b[i] = b"0123456789-.E \n\r\0"[rng.random_range(0..17)],
                    }
                }
                b
            }
            1 => {
                // Lines: delete, duplicate or swap.
                for _ in 0..rng.random_range(1..4) {
                    let i = rng.random_range(0..lines.len());
                    let j = rng.random_range(0..lines.len());
                    match rng.random_range(0..3) {
                        0 => {
                            lines.remove(i);
                        }
                        1 => lines.insert(j, lines[i].clone()),
                        _ => lines.swap(i, j),
                    }
                }
                lines.join("\n").into_bytes()
            }
            2 => {
                // A token replaced by junk.
                for _ in 0..rng.random_range(1..3) {
                    let i = rng.random_range(0..lines.len());
                    let mut t: Vec<String> =
                        lines[i].split_whitespace().map(str::to_string).collect();
                    if !t.is_empty() {
                        let k = rng.random_range(0..t.len());
                        t[k] = junk[rng.random_range(0..junk.len())].to_string();
                        lines[i] = t.join(" ");
                    }
                }
                lines.join("\n").into_bytes()
            }
            3 => {
                // A line inserted.
                for _ in 0..rng.random_range(1..3) {
                    let i = rng.random_range(0..=lines.len());
                    lines.insert(i, inserts[rng.random_range(0..inserts.len())].to_string());
                }
                lines.join("\n").into_bytes()
            }
            _ => {
                // Re-encoded and truncated.
                let mut b: Vec<u8> = [0xFF, 0xFE]
                    .into_iter()
                    .chain(base.encode_utf16().flat_map(u16::to_le_bytes))
                    .collect();
                let n = rng.random_range(0..b.len());
                b.truncate(n);
                b
            }
        };
        let result =
            std::panic::catch_unwind(|| zemax::from_bytes(&bytes, &GlassCatalogs::builtin()));
        let Ok(parsed) = result else {
            panic!(
                "reader panicked on mutation {it}:\n{}",
                String::from_utf8_lossy(&bytes)
            )
        };
        match parsed {
            Err(e) => assert!(!e.message().is_empty(), "mutation {it}: empty message"),
            Ok(z) => {
                accepted += 1;
                let checked = std::panic::catch_unwind(|| {
                    let sys = z.lens.compile();
                    let _ = trace_fan(&sys, 0.0);
                    let again = zemax::to_string(&z.lens, Some(&z.extras));
                    zemax::from_str(&again, &GlassCatalogs::builtin())
                        .map(|b| (b.lens.surfaces.len(), b.lens.object))
                        .map_err(|e| format!("{e}\n{again}"))
                });
                match checked {
                    Ok(Ok((n, object))) => {
                        assert_eq!(n, z.lens.surfaces.len(), "mutation {it}");
                        assert_eq!(object, z.lens.object, "mutation {it}");
                    }
                    Ok(Err(e)) => panic!(
                        "mutation {it}: accepted lens does not read back: {e}\nfrom:\n{}",
                        String::from_utf8_lossy(&bytes)
                    ),
                    Err(_) => panic!(
                        "accepted lens misbehaved on mutation {it}:\n{}",
                        String::from_utf8_lossy(&bytes)
                    ),
                }
            }
        }
    }
    assert!(
        accepted > 500,
        "the fuzzer should also exercise accepted lenses ({accepted})"
    );
}

#[test]
fn fuzz_the_agf_reader() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let base = text("test-catalog.agf");
    let mut accepted = 0;
    for it in 0..3000 {
        let mut b = base.as_bytes().to_vec();
        for _ in 0..rng.random_range(1..5) {
            let i = rng.random_range(0..b.len());
            match rng.random_range(0..3) {
                0 => {
                    b.remove(i);
                }
                1 => b.insert(i, b[i]),
                _ => b[i] = b"0123456789-.E \nNMCDL\0"[rng.random_range(0..21)],
            }
        }
        let r = std::panic::catch_unwind(|| AgfCatalog::from_bytes(&b, "FUZZ"));
        match r {
            Err(_) => panic!(
                "AGF reader panicked on mutation {it}:\n{}",
                String::from_utf8_lossy(&b)
            ),
            Ok(Err(e)) => assert!(!e.message().is_empty()),
            Ok(Ok((c, _))) => {
                accepted += 1;
                for g in &c.glasses {
                    let _ = g.index(LAMBDA_D_NM);
                }
            }
        }
    }
    assert!(accepted > 100, "{accepted}");
}
