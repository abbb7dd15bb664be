"""Strict field check of Kubernetes manifests, and their JSON for the schema check.

  k8s_fields.py OUT.json MANIFEST.yaml...

Parses every YAML document of every manifest (a key twice in one map is an
error, as for kubectl) and walks it along the models of
Debian's python3-kubernetes (the Kubernetes 1.22 API): every key must be a
field of its type there, so a misspelt or misplaced field (`readinesProbe`, a
probe under the pod spec), which a JSON-schema check lets through as an
unknown property, is an error here, as with kubeconform -strict. Values of
type object and int-or-string are not walked; quantities are strings
(`cpu: "2"`), as the models have them. Prints one line per problem
and exits 1 if there is any; writes the documents as a JSON list of
{"file", "doc", "object"} to OUT.json for tests/deploy/k8s_schema.mjs.
"""
import json
import re
import sys

import yaml
from kubernetes.client import models

# A list or a map of a type, as the models' openapi_types spell them.
LIST = re.compile(r"^list\[(.+)\]$")
DICT = re.compile(r"^dict\(str, (.+)\)$")
SCALARS = {"str": str, "int": int, "bool": bool, "float": (int, float)}


class StrictLoader(yaml.SafeLoader):
    """PyYAML keeps the last of two equal keys; kubectl refuses them."""


def construct_mapping(loader, node, deep=False):
    seen = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        if key in seen:
            raise yaml.constructor.ConstructorError(
                None, None, f"duplicate key {key!r}", key_node.start_mark)
        seen.add(key)
    return yaml.SafeLoader.construct_mapping(loader, node, deep)


StrictLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, construct_mapping)


def model_name(doc):
    """V1Deployment for apps/v1 Deployment; None if the document has no kind."""
    api, kind = doc.get("apiVersion"), doc.get("kind")
    if not isinstance(api, str) or not isinstance(kind, str):
        return None
    version = api.split("/")[-1]
    return version[0].upper() + version[1:] + kind


def walk(value, type_name, path, problems):
    m = LIST.match(type_name)
    if m:
        if not isinstance(value, list):
            problems.append(f"{path}: a list expected, got {type(value).__name__}")
            return
        for i, item in enumerate(value):
            walk(item, m.group(1), f"{path}[{i}]", problems)
        return
    m = DICT.match(type_name)
    if m:
        if not isinstance(value, dict):
            problems.append(f"{path}: a map expected, got {type(value).__name__}")
            return
        for key, item in value.items():
            walk(item, m.group(1), f"{path}.{key}", problems)
        return
    if type_name in SCALARS:
        want = SCALARS[type_name]
        # YAML's true is a Python int too; it is no int here.
        if isinstance(value, bool) and type_name != "bool" or not isinstance(value, want):
            problems.append(f"{path}: {type_name} expected, got {value!r}")
        return
    cls = getattr(models, type_name, None)
    if cls is None:  # object, int-or-string (IntOrString), datetime: not walked
        return
    if not isinstance(value, dict):
        problems.append(f"{path}: a {type_name} map expected, got {value!r}")
        return
    fields = {json_key: attr for attr, json_key in cls.attribute_map.items()}
    for key, item in value.items():
        if key not in fields:
            problems.append(f"{path}.{key}: unknown field of {type_name}")
        else:
            walk(item, cls.openapi_types[fields[key]], f"{path}.{key}", problems)


def main(argv):
    if len(argv) < 3:
        print("usage: k8s_fields.py OUT.json MANIFEST.yaml...", file=sys.stderr)
        return 2
    problems, docs = [], []
    for name in argv[2:]:
        try:
            with open(name, encoding="utf-8") as f:
                loaded = list(yaml.load_all(f, Loader=StrictLoader))
        except (OSError, yaml.YAMLError) as e:
            problems.append(f"{name}: {e}")
            continue
        for i, doc in enumerate(d for d in loaded if d is not None):
            where = f"{name} document {i + 1}"
            type_name = model_name(doc) if isinstance(doc, dict) else None
            if type_name is None or getattr(models, type_name, None) is None:
                problems.append(f"{where}: no known apiVersion and kind")
                continue
            walk(doc, type_name, f"{where} ({doc['kind']})", problems)
            docs.append({"file": name, "doc": i + 1, "object": doc})
    with open(argv[1], "w", encoding="utf-8") as f:
        json.dump(docs, f)
    for p in problems:
        print(p)
    print(f"k8s_fields: {len(docs)} documents, {len(problems)} problems")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
