//! Every route the router serves is in the served description, with what its checks
//! answer; every described operation is served.

use std::collections::BTreeSet;

use serde_json::Value;

use super::*;

/// `(METHOD, path)` of every route of `router`, read from its `Debug` form (axum
/// lists each route's path and its `Allow` header there, and has no other way to list
/// them); a route without an `Allow` header (a service taking any method) is `ANY`.
/// Catch-all parameters `{*name}` are written `{name}`, as OpenAPI does.
fn served(router: &Router<Arc<Shared>>) -> BTreeSet<(String, String)> {
    let text = format!("{router:?}");
    let routes = text
        .split("fallback_router:")
        .next()
        .expect("a router's routes");
    let (endpoints, paths) = routes
        .split_once("node: Node { paths: {")
        .expect("axum's Debug of a router lists its paths");
    let methods_of = |id: &str| -> Vec<String> {
        let endpoint = endpoints
            .split(&format!("RouteId({id}): "))
            .nth(1)
            .expect("an endpoint for every path");
        let endpoint = endpoint.split("RouteId(").next().unwrap_or(endpoint);
        match endpoint.split_once("allow_header: Bytes(b\"") {
            Some((_, allow)) => allow
                .split('"')
                .next()
                .unwrap_or("")
                .split(',')
                .filter(|m| *m != "HEAD")
                .map(str::to_owned)
                .collect(),
            None => vec!["ANY".to_owned()],
        }
    };
    let mut served = BTreeSet::new();
    for entry in paths.split("RouteId(").skip(1) {
        let (id, rest) = entry.split_once("): \"").expect("RouteId(n): \"path\"");
        let path = rest.split('"').next().unwrap_or("").replace("{*", "{");
        for method in methods_of(id) {
            served.insert((method, path.clone()));
        }
    }
    served
}

/// The served description.
fn description_json() -> Value {
    serde_json::from_str(openapi_json()).expect("the description is JSON")
}

/// The fields of a path item that are operations.
const METHODS: [&str; 8] = [
    "get", "put", "post", "delete", "options", "head", "patch", "trace",
];

/// `(METHOD, path)` of every operation of the description.
fn described(spec: &Value) -> BTreeSet<(String, String)> {
    let paths = spec["paths"].as_object().expect("paths");
    paths
        .iter()
        .flat_map(|(path, item)| {
            let fields = item.as_object().expect("a path item").keys();
            fields
                .filter(|field| METHODS.contains(&field.as_str()))
                .map(move |method| (method.to_uppercase(), path.clone()))
        })
        .collect()
}

#[test]
fn every_route_is_described_and_every_operation_served() {
    let (router, _) = routes(&|_, routes| routes).split_for_parts();
    let served = served(&router);
    assert!(
        served.contains(&("GET".into(), "/api/scans/{id}".into()))
            && served.contains(&("POST".into(), "/api/scans".into()))
            && served.contains(&("GET".into(), "/api/scans/{id}/files/{path}".into())),
        "the router's routes are read from its Debug form: {served:?}"
    );
    let described = described(&description_json());
    let undescribed: Vec<_> = served.difference(&described).collect();
    assert!(
        undescribed.is_empty(),
        "routes served but not in /api/openapi.json: {undescribed:?}"
    );
    let unserved: Vec<_> = described.difference(&served).collect();
    assert!(
        unserved.is_empty(),
        "operations described but not served: {unserved:?}"
    );
}

#[test]
fn every_operation_describes_its_checks_answers_in_the_error_shape() {
    let spec = description_json();
    for (method, path) in described(&spec) {
        let operation = &spec["paths"][&path][method.to_lowercase()];
        let responses = operation["responses"].as_object().expect("responses");
        let has = |status: &str| responses.contains_key(status);
        let name = format!("{method} {path}");
        assert!(has("421"), "{name} lacks 421 (the Host check)");
        assert!(
            responses.keys().any(|s| s.starts_with('2')),
            "{name} describes no success"
        );
        // Open: the page, health, the description, and the emergency stop (anyone at
        // the instrument can stop it).
        let open = [
            "/",
            "/page/{file}",
            "/api/health",
            "/api/openapi.json",
            "/api/arm/stop",
        ]
        .contains(&path.as_str());
        assert_eq!(operation["security"].is_array(), !open, "{name}: security");
        if !open {
            assert!(has("401") && has("500"), "{name} lacks 401 or 500");
        }
        // An id that is not a whole number is axum's 400, before the handler.
        if path.contains("{id}") || path == "/api/hardware/log" {
            assert!(
                has("400"),
                "{name} lacks 400 (a parameter of the wrong type)"
            );
        }
        if operation["requestBody"].is_object() {
            for status in ["413", "415"] {
                assert!(has(status), "{name} takes a JSON body but lacks {status}");
            }
        }
        for (status, answer) in responses.iter().filter(|(s, _)| s.as_str() >= "400") {
            let answer = match answer["$ref"].as_str() {
                Some(to) => {
                    let name = to.rsplit('/').next().unwrap_or("");
                    &spec["components"]["responses"][name]
                }
                None => answer,
            };
            assert_eq!(
                answer["content"]["application/json"]["schema"]["$ref"],
                "#/components/schemas/Error",
                "{name} {status}: not in the error shape"
            );
        }
    }
    assert_eq!(
        spec["components"]["securitySchemes"]["bearer"]["scheme"],
        "bearer"
    );
}
