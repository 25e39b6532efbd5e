//! bead in a web page: the viewer's [`Session`] built for wasm32, behind a handful of C-ABI
//! exports that the static page's `engine.js` calls (no wasm-bindgen, no JavaScript glue
//! beyond that file). One session per page.
//!
//! The page:
//! 1. hands over its scenes with [`bead_add_scene`] (none: the shipped scenes), then calls
//!    [`bead_start`], which queues the greeting (welcome, scene, panels);
//! 2. sends each message it would send over the served page's WebSocket with
//!    [`bead_message`] (JSON text; the replies are queued);
//! 3. calls [`bead_tick`] ~60 times a second with the wall time since the last tick (the
//!    session advances its panels and queues a frame);
//! 4. after each call, takes the queued messages with [`bead_next`] (1 text, 2 binary frame,
//!    0 none) and reads each at [`bead_out_ptr`], [`bead_out_len`].
//!
//! Strings and frames cross as bytes in the module's memory: the page writes a message into
//! a buffer from [`bead_alloc`] and frees it with [`bead_free`]. Every export is also an
//! ordinary Rust function (tested natively, `tests/exports.rs`). A panic is reported to the
//! page (imported `bead_panic`) before the module traps; the page then says the engine
//! stopped.
//!
//! [`Session`]: bead_viewer::session::Session

use std::collections::VecDeque;
use std::sync::{Arc, Mutex, MutexGuard};

use bead_viewer::protocol::{Encoded, Limits};
use bead_viewer::session::Session;
use bead_viewer::{Catalog, NamedScene};

/// The page's engine: its scenes, its session once started, and the messages not yet taken.
struct Engine {
    scenes: Vec<NamedScene>,
    session: Option<Session>,
    outbox: VecDeque<Encoded>,
    /// The message [`bead_next`] took last, where the page reads it.
    current: Vec<u8>,
}

static ENGINE: Mutex<Engine> = Mutex::new(Engine {
    scenes: Vec::new(),
    session: None,
    outbox: VecDeque::new(),
    current: Vec::new(),
});

fn engine() -> MutexGuard<'static, Engine> {
    // One thread; a poisoned lock (a panic caught natively, in tests) still holds a usable
    // engine.
    ENGINE.lock().unwrap_or_else(|e| e.into_inner())
}

/// The page's clock and panic report (imported from `engine.js`).
#[cfg(target_arch = "wasm32")]
mod host {
    #[link(wasm_import_module = "env")]
    extern "C" {
        fn bead_clock_ms() -> f64;
        fn bead_panic(ptr: *const u8, len: usize);
    }

    /// Seconds of the page's `performance.now()`.
    pub fn now() -> f64 {
        // SAFETY: an imported JavaScript function without arguments or memory access.
        unsafe { bead_clock_ms() / 1000.0 }
    }

    /// Tell the page a panic's message before the module traps.
    pub fn report_panic(message: &str) {
        // SAFETY: the page reads `len` bytes at `ptr`, within `message`, during the call.
        unsafe { bead_panic(message.as_ptr(), message.len()) }
    }
}

fn install_hooks() {
    #[cfg(target_arch = "wasm32")]
    {
        bead_viewer::clock::set_source(host::now);
        std::panic::set_hook(Box::new(|info| host::report_panic(&info.to_string())));
    }
}

/// A buffer of `len` bytes in the module's memory for the page to write a message into;
/// give it back with [`bead_free`].
#[no_mangle]
pub extern "C" fn bead_alloc(len: usize) -> *mut u8 {
    let mut buffer = Vec::<u8>::with_capacity(len.max(1));
    let ptr = buffer.as_mut_ptr();
    std::mem::forget(buffer);
    ptr
}

/// Free a buffer of [`bead_alloc`].
///
/// # Safety
/// `ptr` and `len` are those of one [`bead_alloc`] call, freed once.
#[no_mangle]
pub unsafe extern "C" fn bead_free(ptr: *mut u8, len: usize) {
    // SAFETY: the caller's contract: a buffer of capacity len.max(1) from bead_alloc.
    drop(unsafe { Vec::from_raw_parts(ptr, 0, len.max(1)) });
}

/// The `len` bytes at `ptr` as text (invalid UTF-8 replaced, so that the session's parser
/// reports it where it is).
///
/// # Safety
/// `ptr..ptr + len` is readable for the call (a buffer of [`bead_alloc`] the page filled).
unsafe fn text<'a>(ptr: *const u8, len: usize) -> std::borrow::Cow<'a, str> {
    if len == 0 {
        return std::borrow::Cow::Borrowed("");
    }
    // SAFETY: the caller's contract.
    String::from_utf8_lossy(unsafe { std::slice::from_raw_parts(ptr, len) })
}

/// Add a scene (name, TOML text) to the page's picker, before [`bead_start`]; the first added
/// is loaded on start. Returns the number of scenes so far.
///
/// # Safety
/// Both byte ranges are readable for the call.
#[no_mangle]
pub unsafe extern "C" fn bead_add_scene(
    name_ptr: *const u8,
    name_len: usize,
    text_ptr: *const u8,
    text_len: usize,
) -> u32 {
    // SAFETY: the caller's contract.
    let (name, text) = unsafe { (text(name_ptr, name_len), text(text_ptr, text_len)) };
    let mut engine = engine();
    engine.scenes.push(NamedScene {
        name: name.into_owned(),
        text: text.into_owned(),
    });
    engine.scenes.len() as u32
}

/// Start the session (again, if it ran: a new session with the same scenes) with the scenes
/// added, or the shipped ones when none was; queues the greeting. Returns the messages
/// queued.
#[no_mangle]
pub extern "C" fn bead_start() -> u32 {
    install_hooks();
    let mut engine = engine();
    let catalog = if engine.scenes.is_empty() {
        Catalog::shipped()
    } else {
        Catalog {
            scenes: engine.scenes.clone(),
        }
    };
    let session = Session::new(Arc::new(catalog), Limits::default());
    engine.outbox.clear();
    for message in session.greeting() {
        if let Ok(encoded) = message.encode() {
            engine.outbox.push_back(encoded);
        }
    }
    engine.session = Some(session);
    engine.outbox.len() as u32
}

/// Handle one message of the page (the JSON text it would send over the WebSocket); queues
/// the replies. Returns the messages queued (0 before [`bead_start`]).
///
/// # Safety
/// `ptr..ptr + len` is readable for the call.
#[no_mangle]
pub unsafe extern "C" fn bead_message(ptr: *const u8, len: usize) -> u32 {
    // SAFETY: the caller's contract.
    let message = unsafe { text(ptr, len) };
    let mut engine = engine();
    let Some(session) = engine.session.as_mut() else {
        return 0;
    };
    let replies: Vec<Encoded> = session
        .handle_text(&message)
        .iter()
        .filter_map(|reply| reply.encode().ok())
        .collect();
    engine.outbox.extend(replies);
    engine.outbox.len() as u32
}

/// One tick of the page's clock, `elapsed` wall seconds after the last: the session advances
/// its panels and queues a frame. Returns the messages queued.
#[no_mangle]
pub extern "C" fn bead_tick(elapsed: f64) -> u32 {
    let mut engine = engine();
    let Some(session) = engine.session.as_mut() else {
        return 0;
    };
    if let Some(frame) = session.tick(elapsed) {
        engine.outbox.push_back(frame);
    }
    engine.outbox.len() as u32
}

/// Take the next queued message: 1 (JSON text) or 2 (binary frame), readable at
/// [`bead_out_ptr`] for [`bead_out_len`] bytes until the next call; 0 when none is left.
#[no_mangle]
pub extern "C" fn bead_next() -> u32 {
    let mut engine = engine();
    let (kind, bytes) = match engine.outbox.pop_front() {
        None => (0, Vec::new()),
        Some(Encoded::Text(text)) => (1, text.into_bytes()),
        Some(Encoded::Binary(bytes)) => (2, bytes),
    };
    engine.current = bytes;
    kind
}

/// Where the message [`bead_next`] took is.
#[no_mangle]
pub extern "C" fn bead_out_ptr() -> *const u8 {
    engine().current.as_ptr()
}

/// The length in bytes of the message [`bead_next`] took.
#[no_mangle]
pub extern "C" fn bead_out_len() -> usize {
    engine().current.len()
}
