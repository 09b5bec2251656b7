//! Connections to a remote side (gRPC clients or an HTTP base), made and checked once before
//! the load starts, and the model the load targets.

use anyhow::Context;
use dynaserve_api::json;
use dynaserve_client::Client;
use dynaserve_client::http::{HttpBase, HttpConn};

use super::{Load, Target, Transport};
use crate::transport::{CallError, Conn, http_get};

/// Connections of one remote side, made once and checked before the load starts.
pub(super) struct Remote {
    grpc: Vec<Client>,
    http: Option<HttpBase>,
    url: String,
    /// The model the load targets.
    pub(super) model: String,
}

impl Remote {
    /// Connection `i` (gRPC callers share a few connections; every HTTP caller has its own).
    pub(super) fn conn(&self, i: usize) -> Conn {
        match &self.http {
            Some(b) => Conn::Http(HttpConn::new(b.clone())),
            None => Conn::Grpc(self.grpc[i % self.grpc.len()].clone()),
        }
    }

    /// A connection of its own (a new HTTP/2 connection for gRPC, a new socket for HTTP).
    pub(super) async fn fresh_conn(&self) -> Result<Conn, CallError> {
        match &self.http {
            Some(b) => Ok(Conn::Http(HttpConn::new(b.clone()))),
            None => Ok(Conn::Grpc(Client::connect(&self.url).await?)),
        }
    }
}

fn pick_model(names: Vec<String>, wanted: &str, target: &str) -> anyhow::Result<String> {
    if !wanted.is_empty() {
        anyhow::ensure!(
            names.iter().any(|n| n == wanted),
            "{target} does not serve model {wanted:?} (it serves: {})",
            names.join(", ")
        );
        return Ok(wanted.to_string());
    }
    match names.as_slice() {
        [one] => Ok(one.clone()),
        [] => anyhow::bail!("{target} serves no model"),
        _ => anyhow::bail!(
            "{target} serves several models ({}); pass --model NAME",
            names.join(", ")
        ),
    }
}

/// Connects to a remote side and picks the model to load.
pub(super) async fn connect(target: &Target, load: &Load) -> anyhow::Result<Remote> {
    match target.transport {
        Transport::Grpc => {
            let mut grpc = Vec::new();
            for _ in 0..target.connections.max(1) {
                let c = Client::connect(&target.url).await.map_err(|e| {
                    anyhow::anyhow!(
                        "cannot reach the gRPC server at {}: {e}. Is `dynaserve serve` running \
                         there? (--target sets the URL, --spawn launches a server)",
                        target.url
                    )
                })?;
                grpc.push(c);
            }
            let models = grpc[0]
                .list_models()
                .await
                .with_context(|| format!("ListModels on {}", target.url))?;
            let model = pick_model(
                models.into_iter().map(|m| m.name).collect(),
                &load.model,
                &target.url,
            )?;
            Ok(Remote {
                grpc,
                http: None,
                url: target.url.clone(),
                model,
            })
        }
        Transport::Http => {
            let base = HttpBase::parse(&target.url).map_err(anyhow::Error::msg)?;
            let url = format!("{}/v1/models", target.url.trim_end_matches('/'));
            let text = http_get(&url).await.map_err(|e| {
                anyhow::anyhow!(
                    "cannot reach the HTTP server: {e}. Is `dynaserve serve` running there? \
                     (--target sets the URL, --spawn launches a server)"
                )
            })?;
            let models: json::ListModelsResponse =
                serde_json::from_str(&text).with_context(|| format!("{url}: not a model list"))?;
            let model = pick_model(
                models.models.into_iter().map(|m| m.name).collect(),
                &load.model,
                &target.url,
            )?;
            Ok(Remote {
                grpc: Vec::new(),
                http: Some(base),
                url: target.url.clone(),
                model,
            })
        }
        Transport::Inprocess => anyhow::bail!("in-process targets have no connection"),
    }
}
