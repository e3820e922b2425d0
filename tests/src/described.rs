//! Every answer the tests' client gets is checked against the daemon's OpenAPI
//! description (`GET /api/openapi.json`): its path and method are an operation there
//! (templated paths such as `/api/scans/{id}` matched), and its status is one that
//! operation lists. An unknown path may only get the fallback's 404, an undescribed
//! method on a known path only 405.

use serde_json::Value;

/// `Err` naming the method, path and status when `spec` does not describe the answer.
pub fn check(spec: &Value, method: &str, path: &str, status: u16) -> Result<(), String> {
    let path = path.split(['?', '#']).next().unwrap_or(path);
    let paths = spec["paths"]
        .as_object()
        .ok_or("the description has no paths")?;
    let template = paths
        .iter()
        .filter(|(template, item)| matches(template, item, path))
        .max_by_key(|(template, _)| literal_segments(template))
        .map(|(template, _)| template);
    let Some(template) = template else {
        return match status {
            404 => Ok(()),
            _ => Err(format!(
                "{method} {path} answered {status}, but no path of /api/openapi.json matches it"
            )),
        };
    };
    let operation = &paths[template][method.to_lowercase()];
    if !operation.is_object() {
        return match status {
            405 => Ok(()),
            _ => Err(format!(
                "{method} {path} answered {status}, but /api/openapi.json describes no \
                 {method} {template}"
            )),
        };
    }
    let responses = operation["responses"].as_object();
    if responses.is_some_and(|r| r.contains_key(&status.to_string())) {
        return Ok(());
    }
    let listed: Vec<&String> = responses.map(|r| r.keys().collect()).unwrap_or_default();
    Err(format!(
        "{method} {path} answered {status}, which /api/openapi.json does not list for \
         {method} {template} (it lists {listed:?})"
    ))
}

/// Whether `path` is an instance of `template`: each `{name}` stands for one segment,
/// or for the rest of the path where the path item's `x-rest-of-path` names it.
fn matches(template: &str, item: &Value, path: &str) -> bool {
    let rest_of_path = item["x-rest-of-path"]
        .as_str()
        .map(|name| format!("{{{name}}}"));
    let mut segments = path.split('/');
    for part in template.split('/') {
        if rest_of_path.as_deref() == Some(part) {
            return segments.any(|s| !s.is_empty());
        }
        let Some(segment) = segments.next() else {
            return false;
        };
        let parameter = part.starts_with('{') && part.ends_with('}');
        if !(parameter && !segment.is_empty() || part == segment) {
            return false;
        }
    }
    segments.next().is_none()
}

/// Segments of a template that are not parameters: the most specific template wins.
fn literal_segments(template: &str) -> usize {
    template.split('/').filter(|p| !p.starts_with('{')).count()
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn answers_are_matched_to_templated_paths_and_their_statuses() {
        let spec = json!({"paths": {
            "/api/scans": {"get": {"responses": {"200": {}}}},
            "/api/scans/{id}": {"get": {"responses": {"200": {}, "404": {}}}},
            "/api/scans/{id}/steps": {"get": {"responses": {"200": {}}}},
            "/api/scans/{id}/files/{path}": {"x-rest-of-path": "path",
                "get": {"responses": {"206": {}}}},
        }});
        assert!(check(&spec, "GET", "/api/scans/7", 404).is_ok());
        assert!(check(&spec, "GET", "/api/scans?x=1", 200).is_ok());
        assert!(check(&spec, "GET", "/api/scans/7/files/hdr/a.exr", 206).is_ok());
        let err = check(&spec, "GET", "/api/scans/7/steps", 503).unwrap_err();
        assert!(
            err.contains("GET /api/scans/7/steps answered 503")
                && err.contains("GET /api/scans/{id}/steps"),
            "{err}"
        );
        assert!(check(&spec, "POST", "/api/scans/7", 200).is_err());
        assert!(check(&spec, "POST", "/api/scans/7", 405).is_ok());
        assert!(check(&spec, "GET", "/api/nothing", 404).is_ok());
        assert!(check(&spec, "GET", "/api/nothing", 200).is_err());
        assert!(check(&spec, "GET", "/api/scans/7/other", 200).is_err());
        assert!(check(&spec, "GET", "/api/scans/7/files/", 206).is_err());
    }
}
