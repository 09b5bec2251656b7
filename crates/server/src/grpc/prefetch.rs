//! The request body of a gRPC client stream (Interact), read ahead into one buffer of bytes.
//!
//! HTTP/2 flow control counts bytes, not frames; h2 also caps the memory of the small DATA
//! frames it holds for the application, and closes the whole connection (GOAWAY
//! ENHANCE_YOUR_CALM) past that cap. A client that pipelines thousands of small messages (an
//! Interact action is a few bytes, often one DATA frame each) while the stream steps one at a
//! time would hit it. So a task takes the frames off h2 as they arrive and appends their bytes
//! to one buffer of at most [`READ_AHEAD_BYTES`]; with the buffer full it stops reading, h2's
//! window stays closed and the client waits: backpressure instead of a closed connection.
//! Only a client that sends more than that in tiny frames still meets h2's cap.

use std::pin::Pin;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};

use axum::body::{Body, Bytes};
use axum::http::HeaderMap;
use futures::task::AtomicWaker;
use hyper::body::{Body as _, Frame, SizeHint};
use tokio::sync::Notify;

/// Most bytes read ahead per stream; past it the stream's reading stops until the handler
/// takes some.
pub const READ_AHEAD_BYTES: usize = 1 << 20;

/// What the reading task has seen and the handler not yet taken.
#[derive(Default)]
struct Buffered {
    data: Vec<u8>,
    /// The end of the body: its trailers, or its error.
    end: Option<Result<Option<HeaderMap>, axum::Error>>,
}

struct Shared {
    buffered: Mutex<Buffered>,
    /// Wakes the handler when data or the end arrives.
    reader: AtomicWaker,
    /// Wakes the reading task when the handler took data or went away.
    room: Notify,
    closed: AtomicBool,
}

impl Shared {
    fn lock(&self) -> std::sync::MutexGuard<'_, Buffered> {
        self.buffered.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// The read-ahead body handed to tonic (see the module documentation).
pub struct ReadAhead {
    shared: Arc<Shared>,
    done: bool,
}

impl ReadAhead {
    /// Starts the task reading `body` ahead.
    pub fn new(body: Body) -> ReadAhead {
        let shared = Arc::new(Shared {
            buffered: Mutex::new(Buffered::default()),
            reader: AtomicWaker::new(),
            room: Notify::new(),
            closed: AtomicBool::new(false),
        });
        tokio::spawn(read_ahead(body, shared.clone()));
        ReadAhead {
            shared,
            done: false,
        }
    }
}

/// Moves `body`'s frames into the shared buffer while it has room and the handler is there.
async fn read_ahead(mut body: Body, shared: Arc<Shared>) {
    loop {
        // Wait for room (or for the handler to go away).
        loop {
            if shared.closed.load(Ordering::Acquire) {
                return;
            }
            if shared.lock().data.len() < READ_AHEAD_BYTES {
                break;
            }
            shared.room.notified().await;
        }
        let frame = tokio::select! {
            f = std::future::poll_fn(|cx| Pin::new(&mut body).poll_frame(cx)) => f,
            // The handler took data or went away: look again.
            () = shared.room.notified() => continue,
        };
        let end = match frame {
            Some(Ok(f)) => match f.into_data() {
                Ok(d) => {
                    shared.lock().data.extend_from_slice(&d);
                    shared.reader.wake();
                    continue;
                }
                Err(f) => Ok(f.into_trailers().ok()),
            },
            Some(Err(e)) => Err(e),
            None => Ok(None),
        };
        shared.lock().end = Some(end);
        shared.reader.wake();
        return;
    }
}

impl hyper::body::Body for ReadAhead {
    type Data = Bytes;
    type Error = axum::Error;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, Self::Error>>> {
        if self.done {
            return Poll::Ready(None);
        }
        self.shared.reader.register(cx.waker());
        let mut b = self.shared.lock();
        if !b.data.is_empty() {
            let data = Bytes::from(std::mem::take(&mut b.data));
            drop(b);
            self.shared.room.notify_one();
            return Poll::Ready(Some(Ok(Frame::data(data))));
        }
        match b.end.take() {
            None => Poll::Pending,
            Some(end) => {
                drop(b);
                self.done = true;
                match end {
                    Ok(Some(trailers)) => Poll::Ready(Some(Ok(Frame::trailers(trailers)))),
                    Ok(None) => Poll::Ready(None),
                    Err(e) => Poll::Ready(Some(Err(e))),
                }
            }
        }
    }

    fn is_end_stream(&self) -> bool {
        self.done
    }

    fn size_hint(&self) -> SizeHint {
        SizeHint::default()
    }
}

impl Drop for ReadAhead {
    fn drop(&mut self) {
        // The handler is gone: the reading task stops and drops the body (h2 resets the
        // stream if the client is still sending).
        self.shared.closed.store(true, Ordering::Release);
        self.shared.room.notify_one();
    }
}
