//! The engine's exports called as the page calls them (natively: the same Rust functions the
//! wasm32 build exports): the greeting, a message and its reply, frames on ticks, a bad
//! message answered with an error, never a panic.

use bead_web::{
    bead_add_scene, bead_alloc, bead_free, bead_message, bead_next, bead_out_len, bead_out_ptr,
    bead_start, bead_tick,
};

/// The queued messages: (kind, bytes).
fn take_all() -> Vec<(u32, Vec<u8>)> {
    let mut out = Vec::new();
    loop {
        let kind = bead_next();
        if kind == 0 {
            return out;
        }
        // SAFETY: the engine's current message, read before the next call.
        let bytes = unsafe { std::slice::from_raw_parts(bead_out_ptr(), bead_out_len()) }.to_vec();
        out.push((kind, bytes));
    }
}

/// `text` in a buffer of the engine, as the page writes it.
fn with_buffer<T>(text: &str, f: impl FnOnce(*const u8, usize) -> T) -> T {
    let ptr = bead_alloc(text.len());
    // SAFETY: a buffer of text.len() bytes from bead_alloc.
    unsafe { std::ptr::copy_nonoverlapping(text.as_ptr(), ptr, text.len()) };
    let result = f(ptr, text.len());
    // SAFETY: the same buffer, freed once.
    unsafe { bead_free(ptr, text.len()) };
    result
}

fn json(bytes: &[u8]) -> serde_json::Value {
    serde_json::from_slice(bytes).unwrap()
}

/// One test (the engine is one per process, as one per page).
#[test]
fn the_exports_speak_the_protocol() {
    // Before start: nothing to handle, nothing queued.
    assert_eq!(
        with_buffer(r#"{"type":"play"}"#, |p, n| unsafe { bead_message(p, n) }),
        0
    );
    assert_eq!(bead_tick(0.016), 0);
    let circle = include_str!("../../../scenes/circle.toml");
    let count = with_buffer("ring", |np, nl| {
        with_buffer(circle, |tp, tl| unsafe { bead_add_scene(np, nl, tp, tl) })
    });
    assert_eq!(count, 1);
    let queued = bead_start();
    let greeting = take_all();
    assert_eq!(greeting.len() as u32, queued);
    let kinds: Vec<String> = greeting
        .iter()
        .map(|(kind, bytes)| {
            assert_eq!(*kind, 1, "the greeting is text");
            json(bytes)["type"].as_str().unwrap().to_string()
        })
        .collect();
    assert_eq!(kinds, ["welcome", "scene", "panels"]);
    let welcome = json(&greeting[0].1);
    assert_eq!(welcome["scenes"], serde_json::json!(["ring"]));

    // Ticks advance the running panels and queue a binary frame each.
    let mut t = 0.0;
    for _ in 0..10 {
        assert_eq!(bead_tick(1.0 / 60.0), 1);
        let frames = take_all();
        assert_eq!(frames.len(), 1);
        assert_eq!(frames[0].0, 2, "a frame is binary");
        assert_eq!(&frames[0].1[..4], b"bead");
        let header_len = u32::from_le_bytes(frames[0].1[4..8].try_into().unwrap()) as usize;
        let header = json(&frames[0].1[8..8 + header_len]);
        let panel_t = header["panels"][0]["t"].as_f64().unwrap();
        assert!(panel_t >= t, "{panel_t} after {t}");
        t = panel_t;
    }
    assert!(t > 0.1, "{t}");

    // A message and its reply; a bad message gets an error reply naming its request.
    let queued = with_buffer(r#"{"type":"pause"}"#, |p, n| unsafe { bead_message(p, n) });
    let replies = take_all();
    assert_eq!(replies.len() as u32, queued);
    for bad in [
        "not json",
        r#"{"type":"warp"}"#,
        r#"{"type":"set_param","name":"nope","value":1}"#,
    ] {
        with_buffer(bad, |p, n| unsafe { bead_message(p, n) });
        let replies = take_all();
        let error = replies
            .iter()
            .map(|(_, b)| json(b))
            .find(|m| m["type"] == "error")
            .unwrap_or_else(|| panic!("{bad}: no error reply"));
        assert!(!error["message"].as_str().unwrap().is_empty(), "{error}");
    }
    // Invalid UTF-8 is a message that does not parse, not a crash.
    let bytes = [0xff_u8, 0xfe, b'{'];
    let ptr = bead_alloc(bytes.len());
    unsafe { std::ptr::copy_nonoverlapping(bytes.as_ptr(), ptr, bytes.len()) };
    unsafe { bead_message(ptr, bytes.len()) };
    unsafe { bead_free(ptr, bytes.len()) };
    let replies = take_all();
    assert!(replies.iter().any(|(_, b)| json(b)["type"] == "error"));
    // Start again: a fresh session with the same scenes, its greeting first.
    bead_start();
    let again = take_all();
    assert_eq!(json(&again[0].1)["type"], "welcome");
}
