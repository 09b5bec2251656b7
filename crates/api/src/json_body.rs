//! Reading an HTTP JSON body into a request document ([`crate::json`]): the body must be a JSON
//! object (serde would read an array as a struct's fields in order), and a document that does
//! not fit its type is a [`FieldError`] naming the deepest field reached, or `request` when no
//! field can be named (an empty, truncated or malformed body). Keys the body sent are echoed
//! back cut to a readable length.

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
        FieldError::new(
            shorten(&field, MAX_FIELD_CHARS),
            shorten(&e.into_inner().to_string(), MAX_MESSAGE_CHARS),
        )
    })
}

/// Longest field path echoed back, in characters (an unknown key is part of the path).
const MAX_FIELD_CHARS: usize = 120;
/// Longest message echoed back, in characters.
const MAX_MESSAGE_CHARS: usize = 400;

/// `text` cut to `max` characters, ending in `...` when cut (a body can send a key of any
/// length, and serde repeats it in the path and the message).
fn shorten(text: &str, max: usize) -> String {
    match text.char_indices().nth(max) {
        Some((cut, _)) => format!("{}...", &text[..cut]),
        None => text.to_string(),
    }
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
        // A key of 1000 characters is not echoed in full.
        let body = format!(
            r#"{{"scene": {{"objects": [{{"{}": 1}}]}}}}"#,
            "k".repeat(1000)
        );
        let e = decode::<RolloutRequest>(body.as_bytes()).unwrap_err();
        assert!(
            e.field.starts_with("scene.objects[0].kkk") && e.field.ends_with("..."),
            "{e}"
        );
        assert!(e.field.len() <= 123 && e.message.len() <= 403, "{e}");
        assert_eq!(shorten("abc", 3), "abc");
        assert_eq!(shorten("abcd", 3), "abc...");
    }
}
