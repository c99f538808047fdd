// Mounts Foxglove Studio's App the way its studio-web package does, with settings and layouts in
// memory (a fresh profile every run) and the layout the test asks for: one 3D panel in frame `map`
// with the given topics ticked. The page's URL carries the data source (`?ds=...&ds.url=...`), as
// Foxglove's own deep links do.
/* global React, ReactDOM */
"use strict";

class MemoryConfiguration {
  constructor(values) {
    this.values = new Map(Object.entries(values));
    this.listeners = new Map();
  }
  get(key) {
    return this.values.get(key);
  }
  async set(key, value) {
    this.values.set(key, value);
    for (const listener of this.listeners.get(key) ?? []) {
      listener(value);
    }
  }
  addChangeListener(key, listener) {
    const set = this.listeners.get(key) ?? new Set();
    set.add(listener);
    this.listeners.set(key, set);
  }
  removeChangeListener(key, listener) {
    this.listeners.get(key)?.delete(listener);
  }
}

class MemoryLayouts {
  constructor(initial) {
    this.layouts = new Map(initial.map((layout) => [layout.id, layout]));
  }
  async list() {
    return [...this.layouts.values()];
  }
  async get(_namespace, id) {
    return this.layouts.get(id);
  }
  async put(_namespace, layout) {
    this.layouts.set(layout.id, layout);
    return layout;
  }
  async delete(_namespace, id) {
    this.layouts.delete(id);
  }
  async importLayouts() {}
}

function threeDLayout(topics) {
  const panel = "3D!sonar";
  const data = {
    configById: {
      [panel]: {
        followTf: "map",
        followMode: "follow-none",
        // Seen from above, the room's centre (the sensor) in the middle.
        cameraState: {
          perspective: false,
          distance: 7,
          phi: 0,
          thetaOffset: 0,
          target: [0, 0, 0],
          targetOffset: [0, 0, 0],
          targetOrientation: [0, 0, 0, 1],
          fovy: 45,
          near: 0.01,
          far: 5000,
        },
        topics: Object.fromEntries(topics.map((topic) => [topic, { visible: true }])),
      },
    },
    globalVariables: {},
    userNodes: {},
    // A recording plays at five times its speed (the test plays it to its end).
    playbackConfig: { speed: 5 },
    layout: panel,
  };
  return {
    id: "sonar-test",
    name: "sonar test",
    permission: "CREATOR_WRITE",
    baseline: { data, savedAt: new Date().toISOString() },
    working: undefined,
    syncInfo: undefined,
  };
}

async function main() {
  const studio = window;
  await studio.initI18n();
  const params = new URLSearchParams(window.location.search);
  const topics = (params.get("sonar.topics") ?? "").split(",").filter(Boolean);
  // A fresh start each load: Foxglove keeps its sidebars' state in localStorage, which the pages
  // of one browser profile share. The layout above is the one it opens (its profile names the
  // layout last selected).
  window.localStorage.clear();
  window.localStorage.setItem("studio.profile-data", JSON.stringify({ currentLayoutId: "sonar-test" }));
  const configuration = new MemoryConfiguration({
    "ui.colorScheme": "dark",
    "telemetry.telemetryEnabled": false,
    "telemetry.crashReportingEnabled": false,
  });
  const app = React.createElement(studio.App, {
    deepLinks: [window.location.href],
    appConfiguration: configuration,
    dataSources: [
      new studio.FoxgloveWebSocketDataSourceFactory(),
      new studio.RemoteDataSourceFactory(),
      new studio.McapLocalDataSourceFactory(),
    ],
    layoutStorage: new MemoryLayouts([threeDLayout(topics)]),
    extensionLoaders: [],
    enableGlobalCss: true,
  });
  ReactDOM.render(app, document.getElementById("root"));
}

main().catch((error) => {
  document.body.setAttribute("data-sonar-error", String(error));
  console.error(error);
});
