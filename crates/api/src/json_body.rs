//! Reading an HTTP JSON body into a request document ([`crate::json`]): the body must be a JSON
//! object (serde would read an array as a struct's fields in order), and a document that does
//! not fit its type is a [`FieldError`] naming the deepest field reached, or `request` when no
//! field can be named (an empty, truncated or malformed body).

use serde::de::DeserializeOwned;

use crate::error::FieldError;

/// Decodes `bytes` as a JSON object of type `T`.
pub fn decode<T: DeserializeOwned>(bytes: &[u8]) -> Result<T, FieldError> {
    if bytes.iter().find(|b| !b.is_ascii_whitespace()) != Some(&b'{') {
        return Err(FieldError::new("request", "the body must be a JSON object"));
    }
    let de = &mut serde_json::Deserializer::from_slice(bytes);
    serde_path_to_error::deserialize(de).map_err(|e| {
        let field = field_of(&e.path().to_string());
        FieldError::new(field, e.into_inner().to_string())
    })
}

/// The field named by a path of `serde_path_to_error`: unknown segments (`?`, where the parser
/// lost track of the key) are dropped from the end, and an empty path is `request`.
fn field_of(path: &str) -> String {
    let mut p = path;
    while let Some(rest) = p.strip_suffix('?') {
        p = rest.strip_suffix('.').unwrap_or(rest);
    }
    if p.is_empty() || p == "." {
        "request".to_string()
    } else {
        p.to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::json::RolloutRequest;

    #[test]
    fn errors_name_the_deepest_known_field_or_the_request() {
        let e = decode::<RolloutRequest>(b"[1, 2]").unwrap_err();
        assert_eq!(e.field, "request");
        assert!(decode::<RolloutRequest>(b"").is_err());
        assert_eq!(decode::<RolloutRequest>(b"{").unwrap_err().field, "request");
        assert_eq!(
            decode::<RolloutRequest>(b"{1:2}").unwrap_err().field,
            "request"
        );
        let e =
            decode::<RolloutRequest>(br#"{"scene": {"objects": [{"mass": "x"}]}}"#).unwrap_err();
        assert_eq!(e.field, "scene.objects[0].mass", "{e}");
        assert_eq!(field_of("scene.objects[0].?"), "scene.objects[0]");
        assert_eq!(field_of("?.?"), "request");
        assert_eq!(field_of("steps"), "steps");
    }
}
