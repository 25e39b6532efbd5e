//! `bead serve`: starts, prints its URL, serves the page; a bad scene fails up front.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::process::{Child, Command, Stdio};

const BEAD: &str = env!("CARGO_BIN_EXE_bead");

/// Kills the server when the test ends, however it ends.
struct Server(Child);

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[test]
fn serve_prints_its_url_and_serves_the_page() {
    let scene = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/circle.toml");
    let mut server = Server(
        Command::new(BEAD)
            .args(["serve", scene, "--port", "0"])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    // Keep the reader (and so the pipe) open for the whole test: the server keeps writing.
    let mut stdout = BufReader::new(server.0.stdout.take().unwrap());
    let mut line = String::new();
    stdout.read_line(&mut line).unwrap();
    let url = line
        .trim()
        .strip_prefix("bead viewer at ")
        .unwrap_or_else(|| panic!("unexpected first line: {line:?}"));
    let host_port = url
        .strip_prefix("http://127.0.0.1:")
        .and_then(|rest| rest.strip_suffix('/'))
        .unwrap_or_else(|| panic!("not a loopback URL: {url}"));
    let port: u16 = host_port.parse().unwrap();
    let mut stream = TcpStream::connect(("127.0.0.1", port)).unwrap();
    stream
        .write_all(b"GET / HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n")
        .unwrap();
    let mut response = String::new();
    stream.read_to_string(&mut response).unwrap();
    assert!(response.starts_with("HTTP/1.1 200"), "{response:.100}");
    assert!(response.contains("viewer.js"));
}

#[test]
fn serve_rejects_a_bad_scene_before_listening() {
    let dir = std::env::temp_dir().join(format!("bead-serve-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bad = dir.join("bad.toml");
    std::fs::write(&bad, "title = \"x\"\n[world]\ngravity = [0.0, 1.0]\n").unwrap();
    let output = Command::new(BEAD)
        .args(["serve", bad.to_str().unwrap(), "--port", "0"])
        .output()
        .unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    assert_eq!(output.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        stderr.contains("bad.toml:1:1: the scene has no particles"),
        "{stderr}"
    );
}

#[test]
fn serve_rejects_more_particles_than_the_viewer_takes() {
    let limit = bead_viewer::protocol::Limits::default().max_particles;
    let dir = std::env::temp_dir().join(format!("bead-serve-many-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let many = dir.join("many.toml");
    let mut text = String::from("title = \"many\"\n[world]\ngravity = [0.0, 1.0]\n");
    for i in 0..=limit {
        text.push_str(&format!(
            "[[particle]]\nname = \"p{i}\"\nmass = 1\nposition = [{i}, 0]\n"
        ));
    }
    std::fs::write(&many, text).unwrap();
    let output = Command::new(BEAD)
        .args(["serve", many.to_str().unwrap(), "--port", "0"])
        .output()
        .unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    assert_eq!(output.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        stderr.contains(&format!(
            "many.toml: too many particles for the viewer: {} (limit {limit})",
            limit + 1
        )),
        "{stderr}"
    );
}
