//! Rust client library and scene file formats (JSON scenes, OBJ/PLY meshes) for the Dynaserve WorldModel API.
