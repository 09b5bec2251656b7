//! A headless Chromium driven over the DevTools protocol (CDP) on a pipe
//! (`--remote-debugging-pipe`: commands in on fd 3, answers out on fd 4, each message JSON
//! ended by a NUL byte). The tests need a handful of commands (open a page, evaluate, click,
//! screenshot), so they speak the protocol directly rather than compile a generated client of
//! the whole protocol.
//!
//! The browser is Debian's `chromium` (`.ci/run` installs it), or the executable named by
//! `DYNASERVE_CHROMIUM`. WebGL runs on SwiftShader (software), so no GPU is needed.

#![allow(dead_code)]

use std::io::{BufRead, BufReader, Write};
use std::os::fd::AsRawFd;
use std::os::unix::process::CommandExt;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::{Receiver, RecvTimeoutError, channel};
use std::time::{Duration, Instant};

use serde_json::{Value, json};

/// How long one protocol command may take.
const COMMAND_TIMEOUT: Duration = Duration::from_secs(30);

/// The browser executable: `DYNASERVE_CHROMIUM`, else the first of the usual names on PATH.
pub fn chromium() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("DYNASERVE_CHROMIUM") {
        return Some(PathBuf::from(p));
    }
    let path = std::env::var_os("PATH")?;
    ["chromium", "chromium-browser", "google-chrome"]
        .iter()
        .flat_map(|name| std::env::split_paths(&path).map(move |d| d.join(name)))
        .find(|p| p.is_file())
}

/// A running headless browser with one page attached.
pub struct Browser {
    child: Child,
    to_browser: std::io::PipeWriter,
    from_browser: Receiver<Value>,
    next_id: u64,
    session: Option<String>,
    profile: PathBuf,
}

impl Browser {
    /// Starts the browser with a `width` x `height` CSS-pixel window and a fresh profile.
    pub fn launch(width: u32, height: u32) -> Result<Browser, String> {
        let exe = chromium().ok_or(
            "no chromium found: install Debian's package (apt-get install chromium) or set \
             DYNASERVE_CHROMIUM to a Chromium executable",
        )?;
        static N: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
        let profile = std::env::temp_dir().join(format!(
            "dynaserve-chromium-{}-{}",
            std::process::id(),
            N.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
        ));
        let (child_reads, to_browser) = std::io::pipe().map_err(|e| e.to_string())?;
        let (from_child, child_writes) = std::io::pipe().map_err(|e| e.to_string())?;
        let (r, w) = (child_reads.as_raw_fd(), child_writes.as_raw_fd());
        let mut cmd = Command::new(&exe);
        cmd.args([
            "--headless",
            "--remote-debugging-pipe",
            "--no-sandbox",
            "--no-first-run",
            "--no-default-browser-check",
            "--disable-extensions",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-dev-shm-usage",
            "--hide-scrollbars",
            "--mute-audio",
            "--use-angle=swiftshader",
            "--enable-unsafe-swiftshader",
            "--force-device-scale-factor=1",
        ])
        .arg(format!("--window-size={width},{height}"))
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg("about:blank")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null());
        // SAFETY: only async-signal-safe calls (fcntl, dup2) between fork and exec. The pipe
        // ends are first moved above fd 10 so that placing them on 3 and 4 cannot overwrite
        // one with the other; dup2 clears close-on-exec on the copies.
        unsafe {
            cmd.pre_exec(move || {
                let r2 = libc::fcntl(r, libc::F_DUPFD_CLOEXEC, 10);
                let w2 = libc::fcntl(w, libc::F_DUPFD_CLOEXEC, 10);
                if r2 < 0 || w2 < 0 || libc::dup2(r2, 3) < 0 || libc::dup2(w2, 4) < 0 {
                    return Err(std::io::Error::last_os_error());
                }
                Ok(())
            });
        }
        let child = cmd
            .spawn()
            .map_err(|e| format!("cannot start {}: {e}", exe.display()))?;
        drop((child_reads, child_writes));
        let (tx, rx) = channel();
        std::thread::spawn(move || {
            let mut reader = BufReader::new(from_child);
            loop {
                let mut buf = Vec::new();
                match reader.read_until(0, &mut buf) {
                    Ok(0) | Err(_) => return,
                    Ok(_) => {
                        buf.pop_if(|b| *b == 0);
                        if let Ok(v) = serde_json::from_slice::<Value>(&buf)
                            && tx.send(v).is_err()
                        {
                            return;
                        }
                    }
                }
            }
        });
        let mut b = Browser {
            child,
            to_browser,
            from_browser: rx,
            next_id: 1,
            session: None,
            profile,
        };
        let target = b.call("Target.createTarget", json!({ "url": "about:blank" }))?;
        let target_id = target["targetId"]
            .as_str()
            .ok_or("no targetId")?
            .to_string();
        let attached = b.call(
            "Target.attachToTarget",
            json!({ "targetId": target_id, "flatten": true }),
        )?;
        b.session = Some(
            attached["sessionId"]
                .as_str()
                .ok_or("no sessionId")?
                .to_string(),
        );
        b.call("Page.enable", json!({}))?;
        b.call("Runtime.enable", json!({}))?;
        b.call(
            "Emulation.setDeviceMetricsOverride",
            json!({ "width": width, "height": height, "deviceScaleFactor": 1, "mobile": false }),
        )?;
        Ok(b)
    }

    /// Sends one command (to the page once one is attached) and waits for its result.
    pub fn call(&mut self, method: &str, params: Value) -> Result<Value, String> {
        let id = self.next_id;
        self.next_id += 1;
        let mut msg = json!({ "id": id, "method": method, "params": params });
        if let Some(s) = &self.session {
            msg["sessionId"] = json!(s);
        }
        let mut bytes = serde_json::to_vec(&msg).map_err(|e| e.to_string())?;
        bytes.push(0);
        self.to_browser
            .write_all(&bytes)
            .map_err(|e| format!("{method}: the browser closed its pipe: {e}"))?;
        let deadline = Instant::now() + COMMAND_TIMEOUT;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.from_browser.recv_timeout(left) {
                Ok(v) if v["id"] == json!(id) => {
                    if let Some(e) = v.get("error") {
                        return Err(format!("{method}: {e}"));
                    }
                    return Ok(v["result"].clone());
                }
                Ok(_) => {} // an event, or an answer to an abandoned command
                Err(RecvTimeoutError::Timeout) => return Err(format!("{method}: no answer")),
                Err(RecvTimeoutError::Disconnected) => {
                    return Err(format!("{method}: the browser exited"));
                }
            }
        }
    }

    /// Loads `url` in the page.
    pub fn navigate(&mut self, url: &str) -> Result<(), String> {
        let r = self.call("Page.navigate", json!({ "url": url }))?;
        match r.get("errorText") {
            Some(e) => Err(format!("navigating to {url}: {e}")),
            None => Ok(()),
        }
    }

    /// Evaluates a JavaScript expression in the page (awaiting a promise) and returns its value.
    pub fn eval(&mut self, expression: &str) -> Result<Value, String> {
        let r = self.call(
            "Runtime.evaluate",
            json!({ "expression": expression, "returnByValue": true, "awaitPromise": true }),
        )?;
        if let Some(e) = r.get("exceptionDetails") {
            return Err(format!("{expression}: {e}"));
        }
        Ok(r["result"]["value"].clone())
    }

    /// Polls `expression` every 50 ms until it is truthy and returns its value, or fails after
    /// `timeout` with `describe`'s value (evaluated then) in the message.
    pub fn wait_for(
        &mut self,
        expression: &str,
        timeout: Duration,
        describe: &str,
    ) -> Result<Value, String> {
        let deadline = Instant::now() + timeout;
        loop {
            // While a page loads, the expression may throw (no <body> yet): keep polling.
            let (v, thrown) = match self.eval(expression) {
                Ok(v) => (v, None),
                Err(e) => (Value::Null, Some(e)),
            };
            let truthy =
                !matches!(&v, Value::Null | Value::Bool(false)) && v != json!(0) && v != json!("");
            if truthy {
                return Ok(v);
            }
            if Instant::now() > deadline {
                let state = self.eval(describe).unwrap_or_default();
                return Err(format!(
                    "waited {timeout:?} for `{expression}`; page: {state}; last error: {thrown:?}"
                ));
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// The bounding box of the element `selector` in CSS pixels: `[x, y, width, height]`.
    pub fn rect(&mut self, selector: &str) -> Result<[f64; 4], String> {
        let v = self.eval(&format!(
            "(() => {{ const r = document.querySelector({selector:?}).getBoundingClientRect(); \
             return [r.x, r.y, r.width, r.height]; }})()"
        ))?;
        let a: Vec<f64> = serde_json::from_value(v).map_err(|e| e.to_string())?;
        Ok([a[0], a[1], a[2], a[3]])
    }

    /// Clicks the middle of the element `selector` with the left mouse button, as a person
    /// would (press and release events at that point).
    pub fn click(&mut self, selector: &str) -> Result<(), String> {
        let [x, y, w, h] = self.rect(selector)?;
        let (cx, cy) = (x + w / 2.0, y + h / 2.0);
        for kind in ["mouseMoved", "mousePressed", "mouseReleased"] {
            self.call(
                "Input.dispatchMouseEvent",
                json!({ "type": kind, "x": cx, "y": cy, "button": "left", "clickCount": 1 }),
            )?;
        }
        Ok(())
    }

    /// A PNG screenshot of the element `selector`.
    pub fn screenshot(&mut self, selector: &str) -> Result<Vec<u8>, String> {
        use base64::Engine as _;
        let [x, y, width, height] = self.rect(selector)?;
        let r = self.call(
            "Page.captureScreenshot",
            json!({ "format": "png", "clip": { "x": x, "y": y, "width": width, "height": height, "scale": 1 } }),
        )?;
        let data = r["data"].as_str().ok_or("no screenshot data")?;
        base64::engine::general_purpose::STANDARD
            .decode(data)
            .map_err(|e| e.to_string())
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        self.session = None;
        let _ = self.call("Browser.close", json!({}));
        let deadline = Instant::now() + Duration::from_secs(5);
        while Instant::now() < deadline {
            if let Ok(Some(_)) = self.child.try_wait() {
                break;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
        let _ = std::fs::remove_dir_all(&self.profile);
    }
}

/// A decoded screenshot: RGBA8 pixels.
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub rgba: Vec<u8>,
}

impl Image {
    /// Decodes a PNG (any 8-bit colour type) to RGBA.
    pub fn from_png(bytes: &[u8]) -> Result<Image, String> {
        let mut decoder = png::Decoder::new(bytes);
        decoder.set_transformations(png::Transformations::EXPAND);
        let mut reader = decoder.read_info().map_err(|e| e.to_string())?;
        let mut buf = vec![0; reader.output_buffer_size()];
        let info = reader.next_frame(&mut buf).map_err(|e| e.to_string())?;
        buf.truncate(info.buffer_size());
        let channels = info.color_type.samples();
        let rgba = match channels {
            4 => buf,
            3 => buf
                .chunks(3)
                .flat_map(|p| [p[0], p[1], p[2], 255])
                .collect(),
            2 => buf
                .chunks(2)
                .flat_map(|p| [p[0], p[0], p[0], p[1]])
                .collect(),
            _ => buf.iter().flat_map(|g| [*g, *g, *g, 255]).collect(),
        };
        Ok(Image {
            width: info.width,
            height: info.height,
            rgba,
        })
    }

    /// Distinct colours (RGB) in the image.
    pub fn distinct_colours(&self) -> usize {
        let mut seen = std::collections::HashSet::new();
        for p in self.rgba.chunks(4) {
            seen.insert([p[0], p[1], p[2]]);
        }
        seen.len()
    }

    /// Share of pixels whose RGB differs from the most common colour.
    pub fn non_background_share(&self) -> f64 {
        let mut counts = std::collections::HashMap::new();
        for p in self.rgba.chunks(4) {
            *counts.entry([p[0], p[1], p[2]]).or_insert(0usize) += 1;
        }
        let top = counts.values().max().copied().unwrap_or(0);
        let n = self.rgba.len() / 4;
        if n == 0 {
            return 0.0;
        }
        1.0 - top as f64 / n as f64
    }

    /// Share of pixels whose RGB satisfies `pick` (e.g. a hue one drawn object has).
    pub fn share_matching(&self, pick: impl Fn([u8; 3]) -> bool) -> f64 {
        let n = self.rgba.len() / 4;
        let hits = self
            .rgba
            .chunks(4)
            .filter(|p| pick([p[0], p[1], p[2]]))
            .count();
        hits as f64 / n.max(1) as f64
    }

    /// Share of pixels whose RGB differs by more than `tolerance` in some channel from the
    /// same pixel of `other` (same size).
    pub fn differing_share(&self, other: &Image, tolerance: u8) -> f64 {
        assert_eq!((self.width, self.height), (other.width, other.height));
        let n = self.rgba.len() / 4;
        let differ = self
            .rgba
            .chunks(4)
            .zip(other.rgba.chunks(4))
            .filter(|(a, b)| (0..3).any(|k| a[k].abs_diff(b[k]) > tolerance))
            .count();
        differ as f64 / n.max(1) as f64
    }
}
